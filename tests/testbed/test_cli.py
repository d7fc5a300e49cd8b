"""`testbed run` and `testbed export-urdf`: metrics keys, URDF, and bad input (exit 2, one line)."""

import json
import subprocess
import sys
from pathlib import Path

import dartpy as dart
import pytest

from testbed.tools.cli import main

TESTBED = [sys.executable, "-m", "testbed.tools.cli"]


def test_run_writes_the_foundation_metrics(tmp_path, capsys):
    metrics = tmp_path / "m.json"
    assert main(["run", "--terrain", "flat", "--duration", "1.5", "--metrics", str(metrics),
                 "--out", str(tmp_path / "r.mcap")]) == 0
    data = json.loads(metrics.read_text())
    for key in ("fell", "weight_support_ratio", "realtime_factor", "sim_steps", "wall_s"):
        assert key in data
    assert data["fell"] is False and data["sim_steps"] == 1500
    assert data["weight_support_ratio"] == pytest.approx(1.0, abs=0.01)
    assert "fell=False" in capsys.readouterr().out


def test_walking_run_reports_the_gait_metrics(tmp_path):
    metrics = tmp_path / "m.json"
    assert main(["run", "--gait", "tripod", "--speed", "0.1", "--duration", "4.5", "--metrics", str(metrics),
                 "--out", str(tmp_path / "r.mcap")]) == 0
    data = json.loads(metrics.read_text())
    # 2.2 s start-up (still, calibration poses, level hold), 1 s ramp, then 0.1 m/s: about 0.18 m in 4.5 s
    assert 0.13 < data["distance_m"] < 0.23
    assert 0.07 < data["mean_speed_mps"] < 0.09         # over the 2.3 s after the start-up
    assert data["min_stability_margin_m"] > 0.03
    assert data["target_error_m"] is None and data["ik_limited_ticks"] == 0
    assert data["lateral_drift_m"] < 0.05 * data["distance_m"]


def test_export_urdf_loads_as_19_bodies_and_18_revolute_joints(tmp_path):
    out = tmp_path / "hexapod.urdf"
    assert main(["export-urdf", str(out)]) == 0
    loader = dart.utils.DartLoader()
    skeleton = loader.parseSkeletonString(out.read_text(), "file:///tmp/")
    revolute = sum(skeleton.getJoint(i).getType() == "RevoluteJoint" for i in range(skeleton.getNumJoints()))
    assert skeleton.getNumBodyNodes() == 19 and revolute == 18


@pytest.mark.parametrize("arguments", [
    ["run", "--terrain", "moon"],
    ["run", "--contact", "glue"],
    ["run", "--duration", "0"],
    ["run", "--duration", "-1"],
    ["run", "--duration", "nan"],
    ["run", "--duration", "soon"],
    ["run", "--seed", "-4"],
    ["run", "--config", "/nonexistent.toml"],
    ["run", "--set", "terrain.slope_deg=90"],
    ["run", "--set", "robot.wings=2"],
    ["run", "--set", "nonsense"],
    ["run", "--gait", "gallop"],
    ["run", "--gait", "tripod", "--speed", "0.3"],          # stride longer than the legs allow
    ["run", "--target", "2"],
    ["run", "--target", "a,b"],
    ["run", "--estimator", "kalman"],
    ["run", "--controller", "autopilot"],
    ["run", "--fault", "imu.accel.melt@1s"],
    ["launch"],
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, arguments):
    metrics = tmp_path / "m.json"
    assert main(arguments + ["--metrics", str(metrics)] if arguments[0] == "run" else arguments) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not metrics.exists()


def test_invalid_toml_file_from_a_real_process(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[run]\nduration = \n")
    metrics = tmp_path / "m.json"
    result = subprocess.run(TESTBED + ["run", "--config", str(bad), "--metrics", str(metrics)],
                            capture_output=True, text=True, cwd=Path(__file__).parents[2])
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "invalid TOML" in result.stderr
    assert not metrics.exists()


@pytest.mark.parametrize("argv, gait", [
    (["run", "--speed", "0.1"], "tripod"),                  # a walking command walks the tripod
    (["run", "--turn-rate", "0.2"], "tripod"),
    (["run", "--target", "1,0"], "tripod"),
    (["run", "--gait", "wave", "--speed", "0.04"], "wave"),
    (["run", "--speed", "0"], None),                        # no motion asked: the default (stand)
])
def test_a_motion_command_without_a_gait_walks_the_tripod(argv, gait):
    from testbed.tools.cli import _run_overrides, build_parser
    overrides = _run_overrides(build_parser().parse_args(argv))
    assert overrides.get("run", {}).get("gait") == gait
