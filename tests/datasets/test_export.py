"""`testbed export`: a ROS 2 MCAP that mcap-ros2-support decodes message by message, with the
values of the native file; TUM trajectories that evo reads and scores as we do; CSV tables equal
to `Dataset.table`; bad input in one line, exit 2, nothing written."""

import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pandas
import pytest
from evo.core import metrics, sync
from evo.tools import file_interface
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

import testbed
from datasets.export import export

ROOT = Path(__file__).resolve().parents[2]
TESTBED = [sys.executable, "-m", "testbed.tools.cli"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "run.mcap"
    testbed.run({"run": {"terrain": "slope", "gait": "tripod", "estimator": "ekf", "controller": "posture",
                         "duration": 3.0, "seed": 11}}, out=path)
    return testbed.load(path)


def decoded(path: Path) -> dict[str, list]:
    messages: dict[str, list] = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros in reader.iter_decoded_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, ros))
    return messages


def test_ros2_export_decodes_message_by_message_with_the_native_values(run, tmp_path):
    out = tmp_path / "ros2.mcap"
    export(run, "ros2", out)
    messages = decoded(out)
    imu, encoders, state = run.table("/sensors/imu"), run.table("/sensors/encoders"), run.table("/truth/state")
    assert Counter({topic: len(entries) for topic, entries in messages.items()}) == Counter({
        "/imu": len(imu), "/joint_states": len(encoders), "/truth/joint_states": len(state),
        "/tf": len(run.table("/tf")), "/truth/pose": len(run.table("/truth/pose")),
        "/estimate/pose": len(run.table("/estimate")), "/tf_static": 1})
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for _, m in messages["/imu"]])
    np.testing.assert_array_equal(gyro, imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy())
    assert {m.header.frame_id for _, m in messages["/imu"]} == {"imu"}
    (_, mounting), = messages["/tf_static"]
    (static,) = mounting.transforms
    assert (static.header.frame_id, static.child_frame_id) == ("body", "imu")
    assert [static.transform.translation.x, static.transform.translation.y,
            static.transform.translation.z] == list(run.config.sensors.imu.position)
    truth_joints = np.array([m.position for _, m in messages["/truth/joint_states"]])
    np.testing.assert_array_equal(truth_joints, state.filter(like="joint_positions_").to_numpy())
    assert len(messages["/joint_states"][0][1].name) == 18
    frames = {(tf.header.frame_id, tf.child_frame_id) for _, m in messages["/tf"] for tf in m.transforms}
    assert len({child for _, child in frames}) == 19 and ("body", "leg3_coxa") in frames
    log_times = [log_ns for entries in messages.values() for log_ns, _ in entries]
    for topic in ("/imu", "/truth/pose", "/estimate/pose"):
        for log_ns, message in messages[topic]:
            assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == log_ns
    assert max(log_times) == pytest.approx(3e9, abs=2e6)


def test_tum_trajectories_give_evo_the_attitude_error_we_compute(run, tmp_path):
    export(run, "tum", tmp_path)
    truth = file_interface.read_tum_trajectory_file(str(tmp_path / "truth.tum"))
    estimate = file_interface.read_tum_trajectory_file(str(tmp_path / "estimate.tum"))
    truth, estimate = sync.associate_trajectories(truth, estimate, max_diff=1e-6)
    ape = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    ape.process_data((truth, estimate))
    evo_rmse = ape.get_statistic(metrics.StatisticsType.rmse)

    poses, estimates = run.table("/truth/pose"), run.table("/estimate")
    for table in (poses, estimates):        # the pose's t is its nanosecond stamp, the estimate's the exact time
        table["t_ns"] = np.round(table.pop("t").to_numpy() * 1e9).astype(np.int64)
    merged = pandas.merge(poses, estimates, on="t_ns", suffixes=("", "_estimated"))
    true = Rotation.from_quat(merged[[f"orientation_{a}" for a in "xyzw"]].to_numpy())
    estimated = Rotation.from_quat(merged[[f"quaternion_{a}" for a in "xyzw"]].to_numpy())
    angles = np.degrees((true.inv() * estimated).magnitude())
    assert len(merged) == truth.num_poses > 2500
    assert evo_rmse == pytest.approx(np.sqrt(np.mean(angles ** 2)), rel=1e-6)
    assert 0 < evo_rmse < 5.0
    np.testing.assert_allclose(truth.positions_xyz, merged[[f"position_{a}" for a in "xyz"]].to_numpy(), atol=1e-15)
    # the filter's own body position (start frame): evo, the origins aligned, scores it against the truth
    np.testing.assert_allclose(estimate.positions_xyz, merged[[f"position_{a}_estimated" for a in "xyz"]].to_numpy(),
                               atol=1e-15)
    translation = metrics.APE(metrics.PoseRelation.translation_part)
    truth.align_origin(estimate)
    translation.process_data((truth, estimate))
    walked = float(np.linalg.norm(truth.positions_xyz[-1, :2] - truth.positions_xyz[0, :2]))
    assert walked > 0.02 and translation.get_statistic(metrics.StatisticsType.max) < 0.01     # measured 4 mm


def test_csv_tables_read_back_equal_to_the_dataset_tables(run, tmp_path):
    paths = export(run, "csv", tmp_path)
    assert {path.name for path in paths} >= {"sensors_imu.csv", "estimate.csv", "truth_state.csv", "tf.csv"}
    for topic in ("/sensors/imu", "/estimate", "/truth/support"):
        table = run.table(topic)
        back = pandas.read_csv(tmp_path / f"{topic.strip('/').replace('/', '_')}.csv")
        assert list(back.columns) == list(table.columns)
        np.testing.assert_array_equal(back.to_numpy(dtype=float), table.to_numpy(dtype=float))


@pytest.mark.parametrize("arguments", [
    ["missing.mcap", "--format", "ros2", "--out", "x.mcap"],
    ["RUN", "--format", "ros3", "--out", "x.mcap"],
    ["RUN", "--format", "ros2", "--out", "."],
    ["RUN", "--format", "tum", "--out", "RUN"],
    ["RUN", "--format", "csv"],
    ["NOT_MCAP", "--format", "csv", "--out", "tables"],
])
def test_bad_input_is_one_line_and_exit_2_with_nothing_written(run, tmp_path, arguments):
    (tmp_path / "notes.txt").write_text("not an mcap file")
    substitutions = {"RUN": str(run.path), "NOT_MCAP": str(tmp_path / "notes.txt")}
    argv = [substitutions.get(argument, argument) for argument in arguments]
    before = sorted(tmp_path.iterdir())
    done = subprocess.run([*TESTBED, "export", *argv], cwd=tmp_path, capture_output=True, text=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.splitlines()) == 1 and "Traceback" not in done.stderr
    assert sorted(tmp_path.iterdir()) == before
