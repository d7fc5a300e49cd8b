"""Eq. 2 forward kinematics against DART, closed-form IK round trips, and the Jacobian."""

import numpy as np
import pytest

from testbed import config
from testbed.kinematics import (LegGeometry, UnreachableTarget, foot_jacobian, foot_positions,
                                inverse_kinematics, leg_transform, nominal_stance)
from testbed.robot import LEG_NAMES, build_urdf, foot_offset
from testbed.simulation import load_robot

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)


def random_joint_vectors(rng: np.random.Generator, count: int) -> np.ndarray:
    return rng.uniform(np.tile(GEOM.lower, 6), np.tile(GEOM.upper, 6), (count, 18))


def test_forward_kinematics_matches_dart_body_transforms():
    robot = load_robot(build_urdf(CFG.robot))
    rng = np.random.default_rng(0)
    offset = np.eye(4)
    offset[:3, 3] = foot_offset(CFG.robot)
    worst_position, worst_rotation = 0.0, 0.0
    for q in random_joint_vectors(rng, 50):
        positions = np.zeros(24)
        positions[:3] = rng.normal(size=3) * 0.3      # arbitrary floating-base pose
        positions[3:6] = rng.normal(size=3)
        positions[6:] = q
        robot.setPositions(positions)
        body = robot.getBodyNode("body").getWorldTransform().matrix()
        for leg, name in enumerate(LEG_NAMES):
            tibia = robot.getBodyNode(f"{name}_tibia").getWorldTransform().matrix()
            dart_foot = np.linalg.inv(body) @ tibia @ offset
            eq2 = leg_transform(GEOM, leg, q[3 * leg:3 * leg + 3])
            worst_position = max(worst_position, np.abs(dart_foot[:3, 3] - eq2[:3, 3]).max())
            worst_rotation = max(worst_rotation, np.abs(dart_foot[:3, :3] - eq2[:3, :3]).max())
        assert np.allclose(foot_positions(GEOM, q), [leg_transform(GEOM, i, q[3 * i:3 * i + 3])[:3, 3]
                                                     for i in range(6)], atol=1e-15)
    assert worst_position < 1e-9
    assert worst_rotation < 1e-9


def test_inverse_kinematics_round_trip_over_reachable_workspace():
    rng = np.random.default_rng(1)
    solved = 0
    for q in random_joint_vectors(rng, 400):
        for leg in range(6):
            qi = q[3 * leg:3 * leg + 3]
            target = leg_transform(GEOM, leg, qi)[:3, 3]
            elbow = "up" if qi[2] < 0 else "down"
            try:
                q_ik = inverse_kinematics(GEOM, leg, target, elbow)
            except UnreachableTarget:
                # The other elbow may be outside the joint limits; the generating angles are not.
                pytest.fail(f"reachable target reported unreachable: leg {leg} q {qi}")
            assert np.linalg.norm(leg_transform(GEOM, leg, q_ik)[:3, 3] - target) < 1e-9
            solved += 1
    assert solved == 2400


def test_unreachable_targets_are_reported_not_clamped():
    base = GEOM.base_positions[0]
    outward = np.array([np.cos(GEOM.base_angle[0]), np.sin(GEOM.base_angle[0]), 0.0])
    too_far = base + outward * (GEOM.femur + GEOM.tibia + 0.01)
    with pytest.raises(UnreachableTarget, match="distance"):
        inverse_kinematics(GEOM, 0, too_far)
    behind = base - outward * 0.12 + np.array([0, 0, -0.09])   # coxa would need ~180 degrees
    with pytest.raises(UnreachableTarget, match="joint 1"):
        inverse_kinematics(GEOM, 0, behind)


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    eps = 1e-6
    for q in random_joint_vectors(rng, 30):
        for leg in range(6):
            qi = q[3 * leg:3 * leg + 3]
            numeric = np.column_stack([
                (leg_transform(GEOM, leg, qi + eps * e)[:3, 3] - leg_transform(GEOM, leg, qi - eps * e)[:3, 3]) / (2 * eps)
                for e in np.eye(3)])
            assert np.allclose(foot_jacobian(GEOM, leg, qi), numeric, atol=1e-8)


def test_nominal_stance_is_reachable_with_knees_up():
    feet = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
    for leg in range(6):
        q = inverse_kinematics(GEOM, leg, feet[leg])
        assert q[2] < 0 and abs(q[0]) < 1e-12
