"""The state read-out against DART's own getters, and the compliant contact's per-step kernel
against the readable hard-finger law, through walks with random joint targets."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.runtime.runner import build_simulation
from testbed.world.state import free_joint_transform, free_joint_twist

TOLERANCE = dict(rtol=1e-12, atol=1e-12)


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


def test_pose_and_twist_from_the_root_joint_agree_with_dart_getters():
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
        np.testing.assert_allclose(transform, body.getWorldTransform().matrix(), **TOLERANCE)
        np.testing.assert_allclose(free_joint_twist(transform[:3, :3], robot.getVelocities()),
                                   body.getSpatialVelocity(), **TOLERANCE)


def walk(sim, steps: int, seed: int = 3):
    """Steps with random joint targets around the stance (new ones every 50 steps)."""
    rng = np.random.default_rng(seed)
    targets = sim.standing_targets
    for step in range(steps):
        if step % 50 == 0:
            targets = sim.standing_targets + rng.normal(0.0, 0.1, 18)
        sim.step(targets)
        yield step


@pytest.mark.parametrize("contact", ["compliant", "dart"])
def test_state_read_out_agrees_with_dart_getters_through_a_walk(contact):
    from scipy.spatial.transform import Rotation
    cfg = config.load(overrides={"run": {"terrain": "step", "gait": "tripod", "contact": contact}})
    sim = build_simulation(cfg)
    for _ in walk(sim, 400):
        truth, transform = sim.truth(), sim.body_transform()
        assert truth.t == pytest.approx(sim.world.getTime(), abs=1e-12) and truth.t == sim.time
        np.testing.assert_allclose(transform, sim.body.getWorldTransform().matrix(), **TOLERANCE)
        np.testing.assert_array_equal(truth.body_rotation, transform[:3, :3])
        np.testing.assert_array_equal(truth.body_position, transform[:3, 3])
        np.testing.assert_allclose(free_joint_twist(transform[:3, :3], sim.robot.getVelocities()),
                                   sim.body.getSpatialVelocity(), **TOLERANCE)
        np.testing.assert_allclose(Rotation.from_quat(sim.body_quaternion()).as_matrix(), transform[:3, :3],
                                   rtol=1e-12, atol=1e-12)


def feet_of(state):
    from testbed.model.kinematics import WorldFeet
    return WorldFeet(state["foot_centers"], state["foot_velocities"], state["tibia_spins"], state["tibia_rotations"],
                     state["tibia_origins"])


@pytest.mark.parametrize("terrain", ["step", "rough"])
def test_compliant_contact_kernel_agrees_with_the_readable_law(terrain):
    """Each step the compliant model computes the next step's contact from the state read out (the
    compiled hard_finger_into): the forces, normals, points and flags of the readable hard_finger on
    the terrain's readable sphere_contacts from the same anchors, the anchors it leaves, and the
    forces and tibia-frame points that the next step's addExtForce calls get. The feet in the state
    are kinematics.world_feet's."""
    from testbed.model.kinematics import world_feet
    from testbed.world.contact import hard_finger
    cfg = config.load(overrides={"run": {"terrain": terrain, "gait": "tripod"}})
    sim = build_simulation(cfg)
    model, radius = sim.contact, cfg.robot.foot_radius
    touched = 0
    anchors = model.anchors.copy()
    for _ in walk(sim, 400):
        truth, feet = sim.truth(), feet_of(sim.state())
        for ours, theirs in zip(feet, world_feet(sim.geometry, truth.body_rotation, truth.body_position,
                                                  truth.body_angular_velocity, truth.body_linear_velocity,
                                                  truth.joint_positions, truth.joint_velocities)):
            np.testing.assert_allclose(ours, theirs, **TOLERANCE)
        depth, normals = sim.terrain.sphere_contacts(feet.centers, radius)
        expected, offsets = hard_finger(feet, depth, normals, anchors, cfg.contact, radius, cfg.run.time_step)
        pending = model.pending()
        for ours, theirs in zip(pending[:4], expected[:4]):
            np.testing.assert_allclose(ours, theirs, **TOLERANCE)
        np.testing.assert_array_equal(pending.in_contact, expected.in_contact)
        np.testing.assert_allclose(model.anchors, anchors, **TOLERANCE)
        touching = expected.in_contact
        np.testing.assert_allclose(model._applied_forces[touching], expected.forces[touching], **TOLERANCE)
        np.testing.assert_allclose(model._applied_offsets[touching], offsets[touching], **TOLERANCE)
        anchors = model.anchors.copy()          # the next step starts from the kernel's anchors
        touched += touching.sum()
    assert touched > 500


@pytest.mark.parametrize("terrain", ["step", "rough"])
def test_terrain_with_its_own_candidates_gives_the_same_run(terrain):
    """A terrain without a candidate rule has its candidate boxes found in Python (for the contact
    and the ground check): the same boxes into the same kernels, so the same run."""
    from testbed.world.terrain import make_terrain
    from testbed.world.simulation import Simulation
    from tests.testbed.test_terrain import OwnCandidates
    cfg = config.load(overrides={"run": {"terrain": terrain}})
    make = lambda: make_terrain(terrain, cfg, np.random.default_rng(1))
    ruled, own = Simulation(cfg, make()), Simulation(cfg, OwnCandidates.of(make()))
    assert own.terrain.candidate_rule() is None and ruled.terrain.candidate_rule() is not None
    for _ in zip(walk(ruled, 300), walk(own, 300)):
        for ours, theirs in zip(own.truth(), ruled.truth()):
            np.testing.assert_array_equal(ours, theirs)
        for ours, theirs in zip(own.contact.pending(), ruled.contact.pending()):
            np.testing.assert_array_equal(ours, theirs)
        assert own.body_touches_ground() == ruled.body_touches_ground()


@pytest.mark.parametrize("terrain", ["flat", "slope", "step", "rough"])
def test_compiled_body_ground_check_agrees_with_the_readable_one(terrain):
    """The compiled ground check against corners @ R.T + p and the terrain's readable closest
    distances, over poses in, near and above the ground."""
    from scipy.spatial.transform import Rotation
    sim = build_simulation(config.load(overrides={"run": {"terrain": terrain}}))
    rng = np.random.default_rng(8)
    rotations = Rotation.random(400, random_state=9).as_matrix()
    corners_body = sim.contact._body_corners
    inside = 0
    for index, rotation in enumerate(rotations):
        tilt = 0.3 if index % 2 else 3.0
        rotation = Rotation.from_rotvec(Rotation.from_matrix(rotation).as_rotvec() * tilt / np.pi).as_matrix()
        position = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(-0.02, 0.12)])
        state = sim.state().copy()
        state["rotation"], state["position"] = rotation, position
        sim._state = state
        corners = corners_body @ rotation.T + position
        expected = bool((sim.terrain.closest(corners)[0] < 0.0).any())
        assert sim.body_touches_ground() == expected
        inside += expected
    assert 20 < inside < 380
