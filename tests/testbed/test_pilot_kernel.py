"""The pilot's per-tick kernel against the Python and compiled calls it replaced."""

import math

import numpy as np

from testbed.runtime import config
from testbed.model.kinematics import LegGeometry, joint_targets_or_last, nominal_stance
from testbed.control.pilot import NO_LOOP_GAINS, NO_LOOP_STATE, _body_targets_and_joints, tick_constants
from testbed.control.posture import PostureController, PostureMeasurement, tilted_targets

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)
NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
DT = CFG.run.time_step


def kernel(feet, posture, update, measurement, hold, controller, tilt, last, encoder_feet, gait_frame_feet):
    roll, pitch, height = measurement
    height_error = math.nan if height is None else height - controller.height_reference
    loops = (controller.roll, controller.pitch, controller.height)
    state = tuple(value for loop in loops for value in (loop.integral, loop.output)) if posture else NO_LOOP_STATE
    gains = tuple(value for loop in loops for value in loop.gains) if posture else NO_LOOP_GAINS
    return _body_targets_and_joints(feet, posture, update, roll, pitch, height_error, hold, state,
                                    tick_constants(gains, GEOM), *tilt, last, encoder_feet, gait_frame_feet)


def test_the_tick_kernel_equals_the_posture_startup_and_ik_calls_bit_for_bit():
    rng = np.random.default_rng(3)
    reference = PostureController(CFG.posture, DT, CFG.robot.stance_height)
    compiled = PostureController(CFG.posture, DT, CFG.robot.stance_height)
    last = rng.normal(0.0, 0.3, 18)
    limited = 0
    for k in range(2000):
        # Large errors now and then saturate the loops; some heights are missing; some targets are out of reach.
        scale = 0.5 if k % 50 == 0 else 0.02
        height = None if k % 7 == 0 else CFG.robot.stance_height + rng.normal(0.0, scale)
        measurement = PostureMeasurement(*rng.normal(0.0, scale, 2), height)
        update, hold = k % 11 != 0, k % 13 == 0
        tilt = tuple(rng.normal(0.0, 0.1, 2)) if k % 3 == 0 else (0.0, 0.0)
        feet = NEUTRAL + rng.normal(0.0, 0.05 if k % 17 == 0 else 0.01, NEUTRAL.shape)
        encoder_feet = NEUTRAL + rng.normal(0.0, 0.01, NEUTRAL.shape)
        gait_frame_feet = np.empty((6, 3))
        targets, joints, reachable, state = kernel(feet, True, update, measurement, hold, compiled, tilt, last,
                                                   encoder_feet, gait_frame_feet)
        loops = (compiled.roll, compiled.pitch, compiled.height)
        for i, loop in enumerate(loops):
            loop.integral, loop.output = state[2 * i], state[2 * i + 1]

        if update:
            reference.update(measurement, hold)
        expected = reference.apply(feet)
        if tilt != (0.0, 0.0):
            expected = tilted_targets(expected, *tilt, 0.0)
        expected_joints, expected_reachable = joint_targets_or_last(GEOM, expected, last)
        assert targets.tobytes() == expected.tobytes() and joints.tobytes() == expected_joints.tobytes()
        assert reachable == expected_reachable
        assert gait_frame_feet.tobytes() == reference.to_gait_frame(encoder_feet).tobytes()
        for a, b in zip(loops, (reference.roll, reference.pitch, reference.height)):
            assert (a.integral, a.output) == (b.integral, b.output)
        limited += not reachable
        last = joints
    assert 0 < limited < 2000


def test_without_posture_control_the_kernel_is_the_startup_pose_and_the_ik():
    rng = np.random.default_rng(4)
    last = np.zeros(18)
    for k in range(200):
        feet = NEUTRAL + rng.normal(0.0, 0.01, NEUTRAL.shape)
        tilt = tuple(rng.normal(0.0, 0.1, 2)) if k % 2 else (0.0, 0.0)
        untouched = np.full((6, 3), 7.0)
        targets, joints, reachable, state = _body_targets_and_joints(
            feet, False, False, math.nan, math.nan, math.nan, False, NO_LOOP_STATE, tick_constants(NO_LOOP_GAINS, GEOM),
            *tilt, last, feet, untouched)
        expected = tilted_targets(feet, *tilt, 0.0) if k % 2 else feet
        expected_joints, expected_reachable = joint_targets_or_last(GEOM, expected, last)
        assert targets.tobytes() == expected.tobytes() and joints.tobytes() == expected_joints.tobytes()
        assert reachable == expected_reachable and state == NO_LOOP_STATE and np.all(untouched == 7.0)
