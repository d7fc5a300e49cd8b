"""Leg odometry on a known rigid motion; support polygon and stability margin by hand."""

import numpy as np
import pytest

from testbed import config
from testbed.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.navigation import TargetWalker
from testbed.odometry import LegOdometry
from testbed.stability import stability_margin, support_polygon

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)


def test_odometry_integrates_a_known_planar_motion():
    """Feet fixed in the world, body moving along an arc: odometry recovers the body's path."""
    neutral = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
    odometry = LegOdometry(GEOM)
    world_feet = neutral.copy()
    stance = np.ones(6, bool)
    x = y = yaw = 0.0
    for k in range(200):   # 1 s at 200 Hz: 2 cm forward, 1 cm left, 3 degrees
        c, s = np.cos(yaw), np.sin(yaw)
        body_feet = world_feet.copy()
        body_feet[:, 0] = c * (world_feet[:, 0] - x) + s * (world_feet[:, 1] - y)
        body_feet[:, 1] = -s * (world_feet[:, 0] - x) + c * (world_feet[:, 1] - y)
        odometry.update(inverse_kinematics_all(GEOM, body_feet), stance)
        x, y, yaw = x + 1e-4, y + 5e-5, yaw + np.radians(3.0) / 200
    assert odometry.x == pytest.approx(x - 1e-4, abs=1e-9)
    assert odometry.y == pytest.approx(y - 5e-5, abs=1e-9)
    assert odometry.yaw == pytest.approx(yaw - np.radians(3.0) / 200, abs=1e-9)


def test_odometry_ignores_dropouts_and_feet_in_the_air():
    odometry = LegOdometry(GEOM)
    q = np.tile([0.0, 0.3, -1.5], 6)
    odometry.update(q, np.ones(6, bool))
    odometry.update(np.full(18, np.nan), np.ones(6, bool))
    moved = q.copy()
    moved[0] += 0.2
    odometry.update(moved, np.zeros(6, bool))          # all feet up: nothing to register
    assert odometry.pose == (0.0, 0.0, 0.0)


def test_support_polygon_and_margin():
    square = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0], [0.0, 0.0]])
    polygon = support_polygon(square)
    assert len(polygon) == 4
    area = 0.5 * np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    assert area == pytest.approx(4.0)                                    # counter-clockwise
    assert stability_margin(polygon, np.array([0.0, 0.0])) == pytest.approx(1.0)
    assert stability_margin(polygon, np.array([0.5, 0.2])) == pytest.approx(0.5)
    assert stability_margin(polygon, np.array([3.0, 0.0])) == pytest.approx(-2.0)
    two = support_polygon(np.array([[0.0, 0.0], [1.0, 0.0]]))
    assert stability_margin(two, np.array([0.5, 0.5])) == pytest.approx(-0.5)
    assert stability_margin(np.empty((0, 2)), np.zeros(2)) == -np.inf


def test_target_walker_turns_towards_the_target_and_stops():
    walker = TargetWalker(CFG.gait, (0.0, 1.0))
    command = walker.command((0.0, 0.0, 0.0))          # target to the left: turn left, barely walk
    assert command.wz > 0 and command.vx < 0.01
    command = walker.command((0.0, 0.0, np.pi / 2))    # facing it: walk straight
    assert command.vx == pytest.approx(CFG.gait.speed) and command.wz == pytest.approx(0.0, abs=1e-12)
    assert walker.command((0.0, 0.995, np.pi / 2)).vx == 0.0 and walker.arrived


def test_odometry_rotates_leg_displacements_by_the_given_heading():
    """With a gyro heading of 90 degrees, a step forward in the body frame is a step along +y."""
    neutral = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
    odometry = LegOdometry(GEOM)
    odometry.update(inverse_kinematics_all(GEOM, neutral), np.ones(6, bool), np.pi / 2)
    moved = neutral - [0.01, 0.0, 0.0]         # body 1 cm forward: feet 1 cm back in the body frame
    odometry.update(inverse_kinematics_all(GEOM, moved), np.ones(6, bool), np.pi / 2)
    assert odometry.x == pytest.approx(0.0, abs=1e-12)
    assert odometry.y == pytest.approx(0.01, abs=1e-12)
    assert odometry.yaw == pytest.approx(np.pi / 2)
