"""The start-up routine: still, then calibration poses on planted feet (testbed/startup.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.runtime import config as config_module
from testbed.model.errors import ConfigError
from testbed.runtime.runner import run, true_roll_pitch
from testbed.control.startup import POSES, CalibrationPoses, level_hold, minimum_jerk
from tests.recorders import Collect

TILT = math.radians(12.0)


@pytest.fixture(scope="module")
def poses() -> CalibrationPoses:
    return CalibrationPoses(still=0.3, tilt=TILT, rate=math.radians(100.0), hold=0.2, level_hold=0.2)


def test_minimum_jerk_starts_and_ends_at_rest():
    assert minimum_jerk(0.0) == 0.0 and minimum_jerk(1.0) == 1.0 and minimum_jerk(0.5) == pytest.approx(0.5)
    h = 1e-6
    for s in (0.0, 1.0):
        assert abs(minimum_jerk(s + h) - minimum_jerk(s - h)) / (2 * h) < 1e-5


def test_schedule_visits_every_pose_and_ends_level(poses):
    # Moves of 12, 24, 17, 24 and 12 deg at 100 deg/s mean, five 0.2 s holds after the 0.3 s still.
    path = math.degrees(TILT) * (1 + 2 + math.sqrt(2) + 2 + 1)
    assert poses.end == pytest.approx(0.3 + path / 100.0 + 5 * 0.2)
    assert poses.body_tilt(0.2) == (0.0, 0.0) and poses.body_tilt(poses.end + 0.1) == (0.0, 0.0)
    t = np.arange(0.0, poses.end, 1e-3)
    tilts = np.array([poses.body_tilt(x) for x in t])
    for pose in POSES:
        held = np.all(np.isclose(tilts, TILT * np.array(pose), atol=1e-12), axis=1)
        assert held.sum() >= 199, pose       # held 0.2 s at 1 ms
    # Smooth: no step larger than the peak rate of a minimum-jerk move (1.875 x its mean) allows.
    assert np.max(np.abs(np.diff(tilts, axis=0))) <= 1.875 * math.radians(100.0) * 1e-3 * 1.01


def test_the_level_hold_only_lengthens_the_end(poses):
    longer = CalibrationPoses(still=0.3, tilt=TILT, rate=math.radians(100.0), hold=0.2, level_hold=2.0)
    assert longer.end == pytest.approx(poses.end + 1.8)
    t = np.arange(0.0, longer.end + 0.1, 1e-3)
    assert [longer.body_tilt(x) for x in t[t < poses.end]] == [poses.body_tilt(x) for x in t[t < poses.end]]
    assert all(longer.body_tilt(x) == (0.0, 0.0) for x in t[t >= poses.end - 0.2])


def test_no_tilt_means_no_poses():
    poses = CalibrationPoses(still=0.5, tilt=0.0, rate=1.0, hold=0.2, level_hold=0.2)
    assert poses.end == 0.5 and poses.body_tilt(0.7) == (0.0, 0.0)


def test_the_poses_tilt_the_body_feet_planted():
    """In the physics: the true body reaches each pose within 0.3 deg and the feet stay within 1.5 mm (they roll)."""
    config = config_module.load().replace(run={"gait": "stand", "seed": 7})
    config = config.replace(run={"duration": config.gait.duration_to_walk(0.0)})
    poses = CalibrationPoses.from_gait(config.gait, config.run.duration)
    collect = Collect()
    run(config, collect)
    reached = []
    for tick in collect.ticks:
        commanded = poses.body_tilt(tick.truth.t)
        if commanded != (0.0, 0.0) and poses.body_tilt(tick.truth.t - 0.1) == commanded:     # 0.1 s into a hold
            reached.append(np.subtract(true_roll_pitch(tick.truth), commanded))
    assert len(reached) > 100
    assert np.max(np.abs(reached)) < math.radians(0.3)
    start_feet, end_feet = collect.ticks[0].truth.foot_positions, collect.ticks[-1].truth.foot_positions
    assert np.max(np.linalg.norm(end_feet[:, :2] - start_feet[:, :2], axis=1)) < 1.5e-3


def test_the_rise_to_stance_height_takes_the_first_move(poses):
    start, duration, _, _ = poses._moves[0]
    t = np.arange(0.0, poses.end, 1e-3)
    rise = np.array([poses.rise(x) for x in t])
    assert np.all(rise[t <= start] == 0.0) and np.allclose(rise[t >= start + duration], 1.0, rtol=0.0, atol=1e-9)
    assert np.all(np.diff(rise) >= 0.0)
    assert CalibrationPoses(still=0.5, tilt=0.0, rate=1.0, hold=0.2, level_hold=0.2).rise(0.5) == 1.0


def test_a_body_started_low_on_rough_ground_rises_to_its_stance_height_before_walking():
    """+-3.5 cm blocks, seed 1: the start leaves the body 3.1 cm below its stance height above its
    feet, and the calibration poses then struck a block (a fall at 1.2 s). With the rise, the
    body stands at its stance height above its feet's plane when the walk begins."""
    config = config_module.load(None, {"run": {"terrain": "rough", "seed": 1, "controller": "posture", "estimator": "ekf"},
                                       "terrain": {"rough_amplitude": 0.035}})
    collect = Collect()
    metrics = run(config.replace(run={"duration": config.gait.duration_to_walk(0.0)}), collect).metrics
    assert not metrics["fell"]
    truth = collect.ticks[-1].truth
    feet = truth.foot_positions
    design = np.column_stack([np.ones(6), feet[:, :2]])
    plane = np.linalg.lstsq(design, feet[:, 2] - config.robot.foot_radius, rcond=None)[0]
    height = truth.body_position[2] - plane @ [1.0, *truth.body_position[:2]]
    assert height == pytest.approx(config.robot.stance_height, abs=0.005)


@pytest.mark.parametrize("key, value", [("calibration_tilt_deg", 25.0), ("calibration_tilt_deg", -1.0),
                                        ("calibration_rate_dps", 0.0), ("calibration_hold_time", -0.1),
                                        ("level_hold_time", 0.0)])
def test_bad_calibration_settings_are_refused(key, value):
    with pytest.raises(ConfigError, match="calibration"):
        config_module.load().replace(gait={key: value})


@pytest.mark.parametrize("value, message", [("never", 'must be a number of seconds or "auto"'),
                                            (True, "must be a number or a string")])
def test_a_level_hold_that_is_neither_seconds_nor_auto_is_refused(value, message):
    with pytest.raises(ConfigError, match=message):
        config_module.load().replace(gait={"level_hold_time": value})


def test_an_auto_level_hold_is_a_twentieth_of_a_run_to_40_s_then_grows_with_its_square_within_its_bounds():
    assert [level_hold("auto", duration) for duration in (2.0, 4.0, 10.0, 30.0, 40.0, 60.0, 80.0, 120.0, 170.0, 600.0)] == \
        pytest.approx([0.2, 0.2, 0.5, 1.5, 2.0, 4.5, 8.0, 18.0, 20.0, 20.0])
    assert level_hold(0.7, 600.0) == 0.7 and level_hold(3.0, 4.0) == 3.0      # seconds are taken as given


def test_the_default_start_up_leaves_a_short_run_its_walk_and_holds_a_long_one_level_longer():
    config = config_module.load()
    assert config.gait.level_hold_time == "auto"
    short, long, longest = (config.replace(run={"duration": duration}) for duration in (4.0, 30.0, 600.0))
    assert short.startup_time == pytest.approx(2.19, abs=1e-3) and long.startup_time == pytest.approx(3.49, abs=1e-3)
    assert longest.startup_time == pytest.approx(21.99, abs=1e-3)
    assert config.replace(gait={"level_hold_time": 0.2}, run={"duration": 30.0}).startup_time == pytest.approx(2.19, abs=1e-3)


@pytest.mark.parametrize("walking", [0.0, 1.0, 8.0, 15.0, 30.0, 100.0])
def test_a_run_long_enough_to_walk_leaves_that_much_after_its_start_up(walking):
    gait = config_module.load().gait
    duration = gait.duration_to_walk(walking)
    assert duration - gait.startup_time(duration) == pytest.approx(walking, abs=1e-9)
