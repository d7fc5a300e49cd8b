"""Stance paths that roll: a planted foot's target moves by its sphere's rolling, dphi x (r n),
dphi the tibia's turn (testbed/control/rolling.py)."""

import numpy as np
from scipy.spatial.transform import Rotation

from testbed.control.rolling import StanceRolling, ground_normal, sphere_rolling
from testbed.model.kinematics import LegGeometry, leg_transform
from testbed.runtime import config

RADIUS = 0.01
UP = np.array([0.0, 0.0, 1.0])
LEVEL_FEET = np.column_stack([np.cos(np.arange(6)), np.sin(np.arange(6)), np.full(6, -0.1)])   # on level ground


def geometry_and_stance():
    cfg = config.load()
    geometry = LegGeometry.from_config(cfg.robot)
    joints = np.tile([0.0, 0.3, -1.2], 6)
    joints[0::3] = np.linspace(-0.2, 0.2, 6)             # each leg turned a little differently
    return geometry, joints


def test_the_shift_is_the_tibia_turn_crossed_with_r_up():
    """Against the tibia's rotation from the legs' kinematics: for a small joint step the sphere's
    centre moves by the rotation vector of R_after R_before^T crossed with r z."""
    geometry, joints = geometry_and_stance()
    step = np.tile([0.002, -0.003, 0.004], 6)
    shift = sphere_rolling(joints + step, joints, geometry, RADIUS, UP)
    for leg in range(6):
        before = leg_transform(geometry, leg, joints[3 * leg:3 * leg + 3])[:3, :3]
        after = leg_transform(geometry, leg, (joints + step)[3 * leg:3 * leg + 3])[:3, :3]
        turn = Rotation.from_matrix(after @ before.T).as_rotvec()
        np.testing.assert_allclose(shift[leg], np.cross(turn, [0.0, 0.0, RADIUS]), rtol=0.02, atol=1e-3 * RADIUS * 0.005)
        assert abs(shift[leg, 2]) < 1e-15 and np.linalg.norm(shift[leg]) > 0.5 * RADIUS * 0.001


def test_a_turn_about_the_vertical_rolls_nothing_and_a_tilt_rolls_along_the_leg():
    geometry, joints = geometry_and_stance()
    turned = joints + np.tile([0.05, 0.0, 0.0], 6)
    np.testing.assert_allclose(sphere_rolling(turned, joints, geometry, RADIUS, UP), 0.0, atol=1e-15)
    tilt = 0.02                                          # rad, th2 + th3
    tilted = joints + np.tile([0.0, tilt, 0.0], 6)
    shift = sphere_rolling(tilted, joints, geometry, RADIUS, UP)
    heading = geometry.base_angle + joints[0::3]
    along = np.column_stack([np.cos(heading), np.sin(heading)])
    np.testing.assert_allclose(np.linalg.norm(shift, axis=1), RADIUS * tilt, rtol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(shift[:, :2] * along, axis=1)), RADIUS * tilt, rtol=1e-12)


def test_only_feet_planted_at_both_samples_move_and_the_rolling_adds_up():
    geometry, joints = geometry_and_stance()
    rolling = StanceRolling(geometry, RADIUS, joints)
    feet = np.zeros((6, 3))
    planted = np.array([True, True, True, False, False, True])
    rolling.roll(feet, joints, planted, LEVEL_FEET)                # the first sample only remembers the angles
    np.testing.assert_array_equal(feet, 0.0)
    path = [joints + k * np.tile([0.001, 0.004, -0.001], 6) for k in range(1, 11)]
    now_planted = np.array([True, True, False, True, False, True])
    for angles in path:
        rolling.roll(feet, angles, now_planted, LEVEL_FEET)
    both = planted & now_planted
    expected = sum(sphere_rolling(b, a, geometry, RADIUS, UP) for a, b in zip([joints] + path[:-1], path))
    np.testing.assert_allclose(feet[both], expected[both], rtol=1e-12, atol=1e-15)
    # leg 4 became planted at the first step, so it rolled from there; legs 3 and 5 never
    np.testing.assert_allclose(feet[3], expected[3] - sphere_rolling(path[0], joints, geometry, RADIUS, UP)[3],
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(feet[[2, 4]], 0.0)
    assert np.linalg.norm(feet[0]) > 0.5 * RADIUS * 0.03


def test_on_a_slope_a_turn_about_the_vertical_rolls_the_sphere_across_the_normal():
    """Ground 10 deg up along x_b: a coxa turn d1 about z_b moves the centre by d1 z x (r n)."""
    geometry, joints = geometry_and_stance()
    slope = np.radians(10.0)
    normal = np.array([-np.sin(slope), 0.0, np.cos(slope)])
    turned = joints + np.tile([0.05, 0.0, 0.0], 6)
    shift = sphere_rolling(turned, joints, geometry, RADIUS, normal)
    np.testing.assert_allclose(shift, np.tile(np.cross([0.0, 0.0, 0.05], RADIUS * normal), (6, 1)), rtol=1e-12)
    assert abs(shift[0, 1]) > 0.5 * RADIUS * 0.05 * np.sin(slope)


def test_the_ground_normal_is_the_planted_feet_plane_s():
    feet = np.array([[0.2, 0.1, -0.1], [0.0, 0.2, -0.1], [-0.2, 0.1, -0.1],
                     [0.2, -0.1, -0.1], [0.0, -0.2, -0.1], [-0.2, -0.1, -0.1]])
    slope_x, slope_y = 0.18, -0.05
    feet[:, 2] += slope_x * feet[:, 0] + slope_y * feet[:, 1]
    feet[1, 2] += 0.05                                    # a lifted foot: not planted
    planted = np.array([True, False, True, True, True, True])
    expected = np.array([-slope_x, -slope_y, 1.0]) / np.sqrt(1.0 + slope_x**2 + slope_y**2)
    np.testing.assert_allclose(ground_normal(feet, planted), expected, rtol=1e-9, atol=1e-12)
    two = np.array([True, False, False, True, False, False])
    np.testing.assert_allclose(ground_normal(feet, two), UP, atol=1e-12)
