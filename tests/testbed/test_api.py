"""The Python API (`testbed.run`, `testbed.load`, `testbed.replay`) against the command line on
the same config and seed, and the dataset tables against the recorded streams."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import testbed
from datasets.reader import read_recording
from datasets.dataset import Dataset
from estimators import Estimate, Estimator
from estimators.registry import make_estimator
from sensors.samples import EncoderSample, ImuSample
from testbed.api import make_config
from testbed.model.errors import UserError
from testbed.runtime.metrics import write_metrics
from testbed.tools.cli import main

DURATION = 2.0
RUN = {"run": {"duration": DURATION, "terrain": "flat", "gait": "tripod", "estimator": "ekf"}}
CLI_RUN = ["--duration", "2", "--terrain", "flat", "--gait", "tripod", "--estimator", "ekf"]
WALL_TIME_KEYS = ("wall_s", "realtime_factor", "compile_s")


def deterministic(metrics: dict) -> dict:
    return {key: value for key, value in metrics.items() if key not in WALL_TIME_KEYS}


def as_written(metrics: dict, folder) -> dict:
    """The metrics as `--metrics` writes them (JSON, non-finite values as null)."""
    path = folder / "api_metrics.json"
    write_metrics(path, metrics)
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api")
    return folder, testbed.run(RUN, out=folder / "api.mcap")


def test_import_testbed_loads_no_simulation_dataset_or_gymnasium():
    code = ("import sys, testbed, sensors, estimators; print(sorted(m for m in sys.modules if m.startswith("
            "('dartpy', 'datasets', 'gymnasium', 'pandas', 'testbed.world.simulation', 'testbed.runtime.runner'))))")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"


def test_public_names_load_on_first_use():
    from testbed.control.controller import Controller
    from testbed.world.terrain import Terrain

    assert testbed.Controller is Controller and testbed.Terrain is Terrain
    assert testbed.Dataset is Dataset and callable(testbed.run) and callable(testbed.load)
    with pytest.raises(AttributeError):
        testbed.no_such_name


def test_run_metrics_equal_the_command_line_metrics(recorded):
    folder, result = recorded
    metrics = folder / "cli.json"
    assert main(["run", *CLI_RUN, "--out", str(folder / "cli.mcap"), "--metrics", str(metrics)]) == 0
    cli = json.loads(metrics.read_text())
    assert deterministic(as_written(result.metrics, folder)) == deterministic(cli)
    assert result.metrics["sim_time_s"] == pytest.approx(DURATION)
    assert result.error is None and result.path == folder / "api.mcap" and result.path.is_file()


def test_loaded_run_has_its_config_metrics_and_topics(recorded):
    folder, result = recorded
    dataset = testbed.load(result.path)
    assert dataset.config == make_config(RUN)
    assert dataset.metrics["roll_rmse_deg"] == result.metrics["roll_rmse_deg"]
    assert dataset.metrics["distance_m"] == result.metrics["distance_m"]
    assert {"/sensors/imu", "/sensors/encoders", "/sensors/feet", "/estimate", "/truth/pose"} <= set(dataset.topics)
    assert "/sensors/accel_array" not in dataset.topics      # no accelerometer array by default: no messages


def test_imu_table_has_a_row_per_sample_in_time_order(recorded):
    _, result = recorded
    dataset = testbed.load(result.path)
    imu = dataset.table("/sensors/imu")
    assert abs(len(imu) - dataset.config.sensors.imu.rate * DURATION) <= 1
    assert list(imu.columns) == ["t", "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"]
    assert np.all(np.diff(imu["t"].to_numpy()) > 0)
    samples = [s for s in read_recording(result.path).samples() if isinstance(s, ImuSample)]
    np.testing.assert_array_equal(imu[["accel_x", "accel_y", "accel_z"]].to_numpy(), [s.accel for s in samples])
    np.testing.assert_array_equal(imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(), [s.gyro for s in samples])
    # standing still at first: the accelerometer reads about +g along the body's z
    assert imu["accel_z"][(imu["t"] > 0.05) & (imu["t"] < 0.3)].mean() == pytest.approx(9.81, abs=0.1)


def test_joint_arrays_are_named_by_leg_and_link(recorded):
    _, result = recorded
    dataset = testbed.load(result.path)
    encoders = dataset.table("/sensors/encoders")
    assert abs(len(encoders) - dataset.config.sensors.encoder.rate * DURATION) <= 1
    names = [f"positions_leg{leg}_{link}" for leg in range(1, 7) for link in ("coxa", "femur", "tibia")]
    assert list(encoders.columns) == ["t", *names]
    samples = [s for s in read_recording(result.path).samples() if isinstance(s, EncoderSample)]
    np.testing.assert_array_equal(encoders[names].to_numpy(), [s.positions for s in samples])


def test_truth_estimate_and_command_tables(recorded):
    _, result = recorded
    dataset = testbed.load(result.path)
    pose = dataset.table("/truth/pose")
    assert abs(len(pose) - DURATION / dataset.config.run.time_step) <= 1
    assert pose["position_z"].iloc[-1] == pytest.approx(dataset.config.robot.stance_height, abs=0.02)
    state = dataset.table("/truth/state")
    rotation = state[[f"body_rotation_{row}{column}" for row in range(3) for column in range(3)]].to_numpy()
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", rotation.reshape(-1, 3, 3), rotation.reshape(-1, 3, 3)),
                               np.broadcast_to(np.eye(3), (len(state), 3, 3)), atol=1e-9)
    estimate = dataset.table("/estimate")
    recorded_estimates = read_recording(result.path).estimates()
    np.testing.assert_array_equal(estimate["roll"], [e.roll for e in recorded_estimates])
    np.testing.assert_array_equal(estimate["body_height"],
                                  [np.nan if e.body_height is None else e.body_height for e in recorded_estimates])
    assert {"attitude_cov_00", "attitude_cov_22", "quaternion_w"} <= set(estimate.columns)
    command = dataset.table("/command")
    assert {"body_twist_vx", "phase_leg1", "swinging_leg6", "foot_targets_leg3_z"} <= set(command.columns)
    assert command["swinging_leg1"].dtype == bool
    support = dataset.table("/truth/support")
    assert support["polygon_v3_x"].notna().all() and "stability_margin" in support


def test_unknown_topic_is_a_user_error(recorded):
    _, result = recorded
    with pytest.raises(UserError, match="no topic /sensors/lidar"):
        testbed.load(result.path).table("/sensors/lidar")


def test_replay_equals_the_command_line_replay(recorded, tmp_path):
    _, result = recorded
    replayed = testbed.replay(testbed.load(result.path), "vqf")
    assert main(["replay", str(result.path), "--estimator", "vqf", "--metrics", str(tmp_path / "r.json")]) == 0
    cli = json.loads((tmp_path / "r.json").read_text())
    assert deterministic(as_written(replayed.metrics, tmp_path)) == deterministic(cli)
    assert replayed.metrics["estimator"] == "vqf" and replayed.path is None


def test_run_takes_a_toml_file_and_part_instances(tmp_path, capsys):
    toml = tmp_path / "short.toml"
    toml.write_text('[run]\nduration = 0.5\nestimator = "ekf"\n')
    config = make_config(toml)
    result = testbed.run(toml, estimator=make_estimator("complementary", config), progress=True)
    assert "0.5/0.5 s simulated" in capsys.readouterr().err
    assert result.path is None and result.error is None
    assert result.metrics["sim_time_s"] == pytest.approx(0.5)
    assert result.metrics["roll_rmse_deg"] is None      # scored after the first second only


def test_an_estimator_is_given_only_its_sample_types():
    class ImuTypesSeen(Estimator):
        sample_types = (ImuSample,)

        def __init__(self):
            super().__init__()
            self.seen: list[type] = []

        def update(self, sample):
            self.seen.append(type(sample))
            return Estimate(sample.t, np.array([0.0, 0.0, 0.0, 1.0]), 0.0, 0.0, 0.0)

    estimator = ImuTypesSeen()
    testbed.run({"run": {"duration": 0.3, "gait": "tripod"}}, estimator=estimator)
    assert set(estimator.seen) == {ImuSample} and len(estimator.seen) == pytest.approx(300, abs=2)
