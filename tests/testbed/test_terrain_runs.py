"""Short walks on a course and on a height map with both contact models, and a run that ends
where the built terrain ends."""

import json

import numpy as np
import pytest

from testbed.runtime import config
from testbed.runtime.runner import run
from testbed.tools.cli import main

WALK = {"gait": "tripod", "estimator": "ekf", "controller": "posture", "duration": 2.5, "seed": 31}
COURSE = [{"kind": "flat", "length": 0.6}, {"kind": "ramp", "length": 0.6, "angle_deg": 10.0},
          {"kind": "rough", "length": 0.8, "amplitude": 0.01, "cell": 0.1}, {"kind": "step", "height": -0.02},
          {"kind": "flat", "length": 1.0}]
FAST_START = {"calibration_tilt_deg": 0.0}


def recorded_boxes_match(path, terrain) -> None:
    """The /terrain topic of a recording holds the boxes the run simulated."""
    from datasets.reader import read_recording
    from scipy.spatial.transform import Rotation
    boxes = read_recording(path).terrain()
    np.testing.assert_allclose(boxes.centers, terrain.boxes.centers, atol=1e-9)
    np.testing.assert_allclose(boxes.sizes, 2 * terrain.boxes.half_extents, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(boxes.quaternions).as_matrix(), terrain.boxes.rotations, atol=1e-9)


@pytest.mark.parametrize("contact", ["compliant", "dart"])
def test_a_walk_on_a_course_stays_up(tmp_path, contact):
    from datasets.recorder import McapRecorder
    from testbed.runtime.runner import build_parts
    # The course starts behind the robot's rear feet: the front feet (0.16 m ahead of the body)
    # reach the ramp's foot (0.25 m) after 0.09 m.
    cfg = config.load(overrides={"run": {**WALK, "terrain": "course", "contact": contact}, "gait": FAST_START,
                                 "terrain": {"course": COURSE, "course_start": -0.35}})
    parts = build_parts(cfg)
    metrics = run(cfg, McapRecorder(tmp_path / "run.mcap"), parts=parts).metrics
    assert metrics["fell"] is False and metrics["left_terrain"] is False
    assert metrics["tilt_max_deg"] < 5.0 and metrics["distance_m"] > 0.1
    # the front feet crossed the ramp's foot: its crossing's tilt is part of the run's
    assert 0.0 < metrics["edge_tilt_max_deg"] <= metrics["tilt_max_deg"]
    recorded_boxes_match(tmp_path / "run.mcap", parts.sim.terrain)


@pytest.mark.parametrize("contact", ["compliant", "dart"])
def test_a_walk_on_a_height_map_stays_up(tmp_path, contact):
    y, x = np.mgrid[0:40, 0:60] * 0.05
    np.save(tmp_path / "map.npy", 0.015 * np.sin(3 * x) * np.cos(2 * y))
    cfg = config.load(overrides={"run": {**WALK, "terrain": "heightmap", "contact": contact}, "gait": FAST_START,
                                 "terrain": {"heightmap": str(tmp_path / "map.npy")}})
    metrics = run(cfg).metrics
    assert metrics["fell"] is False and metrics["left_terrain"] is False
    assert metrics["tilt_max_deg"] < 5.0 and metrics["distance_m"] > 0.1


def test_walking_off_the_built_terrain_ends_the_run_without_a_fall(tmp_path, capsys):
    metrics = tmp_path / "m.json"
    code = main(["run", "--terrain", "flat", "--gait", "tripod", "--duration", "6", "--set",
                 "terrain.extent=[-0.5, 0.3, -0.5, 0.5]", "--set", "gait.calibration_tilt_deg=0",
                 "--out", str(tmp_path / "r.mcap"), "--metrics", str(metrics)])
    assert code == 0
    data = json.loads(metrics.read_text())
    assert data["left_terrain"] is True and data["fell"] is False
    assert 0.3 < data["sim_time_s"] < 6.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("testbed: note: the robot left the built terrain at t = ")
