"""Eq. 2 forward kinematics against DART, closed-form IK round trips (leg by leg and all legs in
one compiled call), the Jacobian, and the world-frame feet the simulation reads."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.model.kinematics import (LegGeometry, UnreachableTarget, foot_jacobian, foot_positions,
                                inverse_kinematics, inverse_kinematics_all, inverse_kinematics_legs,
                                joint_targets_or_last, leg_transform, nominal_stance,
                                rows_times_matrix, world_feet)
from testbed.model.robot import LEG_NAMES, build_urdf, foot_offset
from testbed.world.simulation import load_robot

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


def reference_inverse_kinematics(leg: int, target: np.ndarray, elbow: str) -> np.ndarray | None:
    """The closed form written with numpy, independently of testbed.model.kinematics; None: unreachable."""
    c0, s0 = np.cos(GEOM.base_angle[leg]), np.sin(GEOM.base_angle[leg])
    rel = target - GEOM.base_distance[leg] * np.array([c0, s0, 0.0])
    x0, y0, z0 = c0 * rel[0] + s0 * rel[1], -s0 * rel[0] + c0 * rel[1], rel[2]
    a2, a3 = GEOM.femur, GEOM.tibia
    horizontal = np.hypot(x0, y0)
    cos3 = (horizontal**2 + z0**2 - a2**2 - a3**2) / (2 * a2 * a3)
    if not -1 <= cos3 <= 1:
        return None
    th3 = -np.arccos(cos3) if elbow == "up" else np.arccos(cos3)
    heading = np.arctan2(y0, x0)
    wrap = lambda angle: (angle + np.pi) % (2 * np.pi) - np.pi   # noqa: E731
    for th1, reach in ((heading, horizontal), (wrap(heading + np.pi), -horizontal)):
        th2 = wrap(np.arctan2(z0, reach) - np.arctan2(a3 * np.sin(th3), a2 + a3 * np.cos(th3)))
        q = np.array([th1, th2, th3])
        if np.all((q >= GEOM.lower - 1e-12) & (q <= GEOM.upper + 1e-12)):
            return q
    return None


def ik_cases(rng: np.random.Generator, count: int) -> list[tuple[np.ndarray, str]]:
    """Foot target sets: reachable ones from random joints (both elbows, and legs reaching back over
    the hip, the second shoulder branch), and random points that are often out of reach or past a
    joint limit."""
    cases = []
    for q in random_joint_vectors(rng, count):
        feet = np.array([leg_transform(GEOM, leg, q[3 * leg:3 * leg + 3])[:3, 3] for leg in range(6)])
        cases.append((feet, "up" if q[2] < 0 else "down"))
        stance = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
        cases.append((stance + rng.normal(0.0, 0.08, (6, 3)), "up"))
    return cases


def test_all_legs_at_once_give_the_scalar_joints():
    rng = np.random.default_rng(3)
    seen = {"reachable": 0, "distance": 0, "joint": 0, "second branch": 0}
    previous = rng.normal(size=18)
    for feet, elbow in ik_cases(rng, 600):
        q, reachable = inverse_kinematics_legs(GEOM, feet, previous, elbow)
        for leg in range(6):
            angles = q[3 * leg:3 * leg + 3]
            try:
                expected = inverse_kinematics(GEOM, leg, feet[leg], elbow)
            except UnreachableTarget as error:
                assert not reachable[leg]
                np.testing.assert_array_equal(angles, previous[3 * leg:3 * leg + 3])   # the fallback, copied
                seen["distance" if "distance" in error.reason else "joint"] += 1
                continue
            assert reachable[leg]
            np.testing.assert_allclose(angles, expected, rtol=0, atol=1e-12)
            seen["reachable"] += 1
            local = feet[leg] - GEOM.base_positions[leg]
            seen["second branch"] += abs(np.cos(angles[0] - GEOM.base_angle[leg] - np.arctan2(local[1], local[0])) + 1) < 1e-6
    assert min(seen.values()) >= 20, seen


def test_the_controllers_inverse_kinematics_is_the_batched_one():
    rng = np.random.default_rng(5)
    previous = rng.normal(size=18)
    for feet, elbow in ik_cases(rng, 300):
        if elbow != "up":
            continue
        q, all_reached = joint_targets_or_last(GEOM, feet, previous)
        expected, reachable = inverse_kinematics_legs(GEOM, feet, previous)
        np.testing.assert_allclose(q, expected, rtol=0, atol=1e-12)
        assert all_reached == reachable.all()


def test_the_compiled_products_are_numpys():
    rng = np.random.default_rng(6)
    for _ in range(2000):
        points, matrix = rng.normal(0.0, 0.1, (6, 3)), rng.normal(0.0, 1.0, (3, 3))
        np.testing.assert_allclose(rows_times_matrix(points, matrix, np.empty((6, 3))), points @ matrix,
                                   rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(rows_times_matrix(points, matrix.T, np.empty((6, 3))), points @ matrix.T,
                                   rtol=1e-12, atol=1e-15)


def test_inverse_kinematics_agrees_with_an_independent_numpy_version():
    rng = np.random.default_rng(4)
    for feet, elbow in ik_cases(rng, 200):
        q, reachable = inverse_kinematics_legs(GEOM, feet, elbow=elbow)
        for leg in range(6):
            expected = reference_inverse_kinematics(leg, feet[leg], elbow)
            assert reachable[leg] == (expected is not None)
            if expected is None:
                assert np.isnan(q[3 * leg:3 * leg + 3]).all()
            else:
                np.testing.assert_allclose(q[3 * leg:3 * leg + 3], expected, rtol=0, atol=1e-12)


def test_inverse_kinematics_all_names_the_first_unreachable_leg():
    feet = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
    feet[3] += [0.0, 0.0, -0.5]
    with pytest.raises(UnreachableTarget, match="leg 4: .* distance") as error:
        inverse_kinematics_all(GEOM, feet)
    assert error.value.leg == 3


def test_world_feet_match_dart_transforms_and_velocities():
    robot = load_robot(build_urdf(CFG.robot))
    body = robot.getBodyNode("body")
    tibias = [robot.getBodyNode(f"{name}_tibia") for name in LEG_NAMES]
    offset = foot_offset(CFG.robot)
    rng = np.random.default_rng(5)
    for q in random_joint_vectors(rng, 20):
        positions = np.concatenate([rng.normal(size=3) * 0.3, rng.normal(size=3), q])
        robot.setPositions(positions)
        robot.setVelocities(rng.normal(size=24))
        transform = body.getWorldTransform().matrix()
        rotation, twist = transform[:3, :3], body.getSpatialVelocity()
        velocities = robot.getVelocities()
        feet = world_feet(GEOM, rotation, transform[:3, 3], rotation @ twist[:3], rotation @ twist[3:], q, velocities[6:])
        for leg, tibia in enumerate(tibias):
            matrix = tibia.getWorldTransform().matrix()
            np.testing.assert_allclose(feet.tibia_rotations[leg], matrix[:3, :3], atol=1e-12)
            np.testing.assert_allclose(feet.tibia_origins[leg], matrix[:3, 3], atol=1e-12)
            np.testing.assert_allclose(feet.centers[leg], matrix[:3, :3] @ offset + matrix[:3, 3], atol=1e-12)
            np.testing.assert_allclose(feet.velocities[leg], tibia.getLinearVelocity(offset), atol=1e-12)
            np.testing.assert_allclose(feet.spins[leg], tibia.getAngularVelocity(), atol=1e-12)
