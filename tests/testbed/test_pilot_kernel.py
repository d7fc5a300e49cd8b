"""The pilot's per-tick kernel against the readable steps it compiles: posture correction,
start-up tilt, inverse kinematics, and the encoders' feet in the gait frame."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.control.pilot import (SWING_LOWERING, PosturePilot, body_targets_and_joints,
                                   body_targets_and_joints_readable)
from testbed.control.posture import PostureCorrection, gait_frame_positions

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)
NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)


def test_the_tick_kernel_is_the_readable_correction_tilt_and_ik():
    rng = np.random.default_rng(3)
    last = rng.normal(0.0, 0.3, 18)
    limited = 0
    for k in range(2000):
        # Large corrections now and then; some targets are out of reach; the tilt only now and then.
        scale = 0.3 if k % 50 == 0 else 0.02
        correction = PostureCorrection(*rng.normal(0.0, scale, 2), rng.normal(0.0, 0.01))
        tilt = tuple(rng.normal(0.0, 0.1, 2)) if k % 3 == 0 else (0.0, 0.0)
        feet = NEUTRAL + rng.normal(0.0, 0.05 if k % 17 == 0 else 0.01, NEUTRAL.shape)
        encoder_feet = NEUTRAL + rng.normal(0.0, 0.01, NEUTRAL.shape)
        gait_frame_feet = np.empty((6, 3))
        targets, joints, reachable = body_targets_and_joints(feet, tuple(correction), tilt, GEOM.arrays, last,
                                                             encoder_feet, gait_frame_feet)
        expected, expected_joints, expected_reachable = body_targets_and_joints_readable(feet, correction, tilt,
                                                                                         GEOM, last)
        np.testing.assert_allclose(targets, expected, rtol=1e-12, atol=1e-15)
        assert reachable == expected_reachable
        np.testing.assert_allclose(joints, expected_joints, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gait_frame_feet, gait_frame_positions(encoder_feet, correction),
                                   rtol=1e-12, atol=1e-15)
        limited += not reachable
        last = joints
    assert 0 < limited < 2000


def test_with_no_correction_and_no_tilt_the_kernel_is_the_ik_alone():
    rng = np.random.default_rng(4)
    last = np.zeros(18)
    for _ in range(200):
        feet = NEUTRAL + rng.normal(0.0, 0.01, NEUTRAL.shape)
        gait_frame_feet = np.empty((6, 3))
        targets, joints, reachable = body_targets_and_joints(feet, (0.0, 0.0, 0.0), (0.0, 0.0), GEOM.arrays, last,
                                                             feet, gait_frame_feet)
        np.testing.assert_array_equal(targets, feet)
        np.testing.assert_array_equal(gait_frame_feet, feet)
        _, expected_joints, expected_reachable = body_targets_and_joints_readable(feet, PostureCorrection(),
                                                                                  (0.0, 0.0), GEOM, last)
        np.testing.assert_allclose(joints, expected_joints, rtol=0, atol=1e-12)
        assert reachable == expected_reachable


def test_a_swing_raised_past_the_femurs_limit_is_lowered_by_the_least_step_that_reaches():
    """Leg 1's swing 8 cm above the stance and a fifth nearer the hip folds the knee past the
    femur's 90 deg limit: the pilot lowers the swing feet's targets by the least of
    SWING_LOWERING's steps that every leg reaches, and leaves the stance feet alone."""
    cfg = config.load()
    geometry = LegGeometry.from_config(cfg.robot)
    stance = nominal_stance(geometry, cfg.robot.stance_radius, cfg.robot.stance_height, cfg.robot.foot_radius)
    pilot = PosturePilot.from_config(cfg)
    pilot.start(inverse_kinematics_all(geometry, stance))
    feet = pilot.gait.state.feet.copy()
    feet[0, :2] *= 0.8
    feet[0, 2] += 0.08
    pilot.gait.state.swinging[0] = True
    last = pilot.joint_targets.copy()
    _, _, reachable = body_targets_and_joints(feet, (0.0, 0.0, 0.0), (0.0, 0.0), geometry.arrays, last,
                                              pilot.encoder_feet, np.empty((6, 3)))
    assert not reachable
    targets, joints, reachable = pilot._lower_swings_to_reach(feet, (0.0, 0.0), last)
    assert reachable
    drop = min(SWING_LOWERING, key=lambda step: abs(step - (feet[0, 2] - targets[0, 2])))
    assert feet[0, 2] - targets[0, 2] == pytest.approx(drop, abs=1e-12)
    higher = max([step for step in SWING_LOWERING if step < drop], default=0.0)
    raised = feet.copy()
    raised[0, 2] -= higher
    assert not body_targets_and_joints(raised, (0.0, 0.0, 0.0), (0.0, 0.0), geometry.arrays, last,
                                       pilot.encoder_feet, np.empty((6, 3)))[2]
    np.testing.assert_allclose(targets[1:], feet[1:], atol=1e-12)
    np.testing.assert_allclose(targets[0, :2], feet[0, :2], atol=1e-12)
    assert np.degrees(joints[1]) <= 90.0
