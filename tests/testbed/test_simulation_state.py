"""The state read-out's body pose and twist, computed from the root FreeJoint's coordinates, against
DART's own getters bit for bit (signs of zeros included): the truth and every recorded byte rest on them.

One case is left out: angular or linear rates with exact zeros beside non-zero ones (never met
after the first step of a run) can give a twist component of -0.0 where DART gives 0.0 or back."""

import numpy as np
import pytest

from testbed import config
from testbed.runner import build_simulation
from testbed.simulation import free_joint_transform, free_joint_twist


def assert_same_bits(ours: np.ndarray, dart: np.ndarray) -> None:
    ours, dart = np.asarray(ours), np.asarray(dart)
    assert ours.shape == dart.shape
    assert np.array_equal(ours.view(np.uint64), dart.view(np.uint64)), np.abs(ours - dart).max()


def rotation_vectors(rng: np.random.Generator) -> list[np.ndarray]:
    """Around DART's small-angle switch (1e-3 rad), exact zeros of either sign, axis-aligned, large."""
    vectors = [np.zeros(3), np.array([-0.0, 0.0, -0.0]), np.array([1e-3, 0.0, 0.0]), np.array([0.0, -1e-3, 0.0])]
    for axis in range(3):
        for angle in (-3.0, -0.5, 0.5, 3.0):
            vector = np.zeros(3)
            vector[axis] = angle
            vectors.append(vector)
    vectors += [rng.normal(0.0, scale, 3) for scale in (1e-5, 3e-4, 6e-4, 1e-2, 0.3, 2.0) for _ in range(200)]
    return vectors


def test_pose_and_twist_from_the_root_joint_equal_dart_getters_bit_for_bit():
    sim = build_simulation(config.load())
    robot, body = sim.robot, sim.body
    rng = np.random.default_rng(11)
    positions = robot.getPositions()
    for index, vector in enumerate(rotation_vectors(rng)):
        positions[0:3] = vector
        positions[3:6] = rng.choice([0.0, -0.0, 1.0], size=3) * rng.normal(size=3)
        velocities = rng.normal(size=24) if index % 10 else np.zeros(24)     # moving, and at rest
        robot.setPositions(positions)
        robot.setVelocities(velocities)
        transform = free_joint_transform(robot.getPositions())
        assert_same_bits(transform, body.getWorldTransform().matrix())
        assert_same_bits(free_joint_twist(transform[:3, :3], robot.getVelocities()), body.getSpatialVelocity())


@pytest.mark.parametrize("contact", ["compliant", "dart"])
def test_state_read_out_equals_dart_getters_through_a_walk(contact):
    cfg = config.load(overrides={"run": {"terrain": "step", "gait": "tripod", "contact": contact}})
    sim = build_simulation(cfg)
    rng = np.random.default_rng(3)
    targets = sim.standing_targets
    for step in range(400):
        if step % 50 == 0:
            targets = sim.standing_targets + rng.normal(0.0, 0.1, 18)
        sim.step(targets)
        state = sim._state
        assert state.t == sim.time == sim.world.getTime()
        assert_same_bits(state.transform, sim.body.getWorldTransform().matrix())
        assert_same_bits(free_joint_twist(state.transform[:3, :3], sim.robot.getVelocities()),
                         sim.body.getSpatialVelocity())
