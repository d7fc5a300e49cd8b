"""The state read-out's body pose and twist, computed from the root FreeJoint's coordinates, against
DART's own getters bit for bit (signs of zeros included): the truth and every recorded byte rest on them.

One case is left out: angular or linear rates with exact zeros beside non-zero ones (never met
after the first step of a run) can give a twist component of -0.0 where DART gives 0.0 or back."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.runtime.runner import build_simulation
from testbed.world.simulation import free_joint_transform, free_joint_twist


def assert_same_bits(ours: np.ndarray, dart: np.ndarray) -> None:
    ours, dart = np.asarray(ours), np.asarray(dart)
    assert ours.shape == dart.shape and ours.dtype == dart.dtype
    if ours.dtype != np.float64:
        assert np.array_equal(ours, dart)
        return
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
        truth, transform = sim.truth(), sim.body_transform()
        assert truth.t == sim.time == sim.world.getTime()
        assert_same_bits(transform, sim.body.getWorldTransform().matrix())
        assert_same_bits(truth.body_rotation, transform[:3, :3])
        assert_same_bits(truth.body_position, transform[:3, 3])
        assert_same_bits(free_joint_twist(transform[:3, :3], sim.robot.getVelocities()),
                         sim.body.getSpatialVelocity())


def walk(sim, steps: int, seed: int = 3):
    """Steps with random joint targets around the stance (new ones every 50 steps)."""
    rng = np.random.default_rng(seed)
    targets = sim.standing_targets
    for step in range(steps):
        if step % 50 == 0:
            targets = sim.standing_targets + rng.normal(0.0, 0.1, 18)
        sim.step(targets)
        yield step


@pytest.mark.parametrize("terrain", ["step", "rough"])
def test_contact_in_the_read_out_equals_the_contact_model_bit_for_bit(terrain):
    """The read-out computes the next step's compliant contact with the state: the forces, normals,
    points and flags of CompliantContact.compute on the feet of world_feet (its own anchors), and
    addExtForce gets those forces at those points."""
    from testbed.world.contact import CompliantContact
    from testbed.model.kinematics import world_feet
    cfg = config.load(overrides={"run": {"terrain": terrain, "gait": "tripod"}})
    sim = build_simulation(cfg)
    model = CompliantContact(cfg.contact, sim.terrain, cfg.robot.foot_radius)
    touched = 0
    for _ in walk(sim, 400):
        truth = sim.truth()
        feet = world_feet(sim.geometry, truth.body_rotation, truth.body_position, truth.body_angular_velocity,
                          truth.body_linear_velocity, truth.joint_positions, truth.joint_velocities)
        links = np.concatenate([feet.velocities[:, None], feet.spins[:, None], feet.tibia_rotations,
                                feet.tibia_origins[:, None]], axis=1)
        expected, offsets = model.compute(feet.centers, links)
        pending = sim._pending
        for ours, theirs in zip(pending, expected):
            assert_same_bits(ours, theirs)
        assert_same_bits(truth.foot_positions, feet.centers)
        assert_same_bits(sim.compliant.anchors, model.anchors)
        touching = expected.in_contact
        assert sim._pending_bits == sum(1 << leg for leg in range(6) if touching[leg])
        assert_same_bits(sim._applied_forces[touching], expected.forces[touching])
        assert_same_bits(sim._applied_offsets[touching], offsets[touching])
        touched += touching.sum()
    assert touched > 500


@pytest.mark.parametrize("terrain", ["step", "rough"])
def test_terrain_with_its_own_candidates_gives_the_same_run(terrain):
    """A terrain without a candidate rule takes the read-out's Python path for its candidate boxes
    (and the ground check's): the same run bit for bit."""
    from testbed.world.terrain import make_terrain
    from testbed.world.simulation import Simulation
    from tests.testbed.test_terrain import OwnCandidates
    cfg = config.load(overrides={"run": {"terrain": terrain}})
    make = lambda: make_terrain(terrain, cfg, np.random.default_rng(1))
    ruled, own = Simulation(cfg, make()), Simulation(cfg, OwnCandidates.of(make()))
    assert own._candidate_rule is None and ruled._candidate_rule is not None
    for _ in zip(walk(ruled, 300), walk(own, 300)):
        for ours, theirs in zip(own.truth(), ruled.truth()):
            assert_same_bits(ours, theirs)
        for ours, theirs in zip(own._pending, ruled._pending):
            assert_same_bits(ours, theirs)
        assert own.body_touches_ground() == ruled.body_touches_ground()


@pytest.mark.parametrize("terrain", ["flat", "slope", "step", "rough"])
def test_body_ground_check_equals_numpy_corners_in_the_boxes(terrain):
    """The compiled ground check against the numpy version it replaced (corners @ R.T + p, then
    the distances to the terrain's candidate boxes), over poses in, near and above the ground."""
    from scipy.spatial.transform import Rotation
    from testbed.world.terrain import distances_to_boxes
    sim = build_simulation(config.load(overrides={"run": {"terrain": terrain}}))
    rng = np.random.default_rng(8)
    rotations = Rotation.random(400, random_state=9).as_matrix()
    inside = 0
    for index, rotation in enumerate(rotations):
        tilt = 0.3 if index % 2 else 3.0
        rotation = Rotation.from_rotvec(Rotation.from_matrix(rotation).as_rotvec() * tilt / np.pi).as_matrix()
        position = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(-0.02, 0.12)])
        sim._frame = sim._frame.copy()
        sim._frame[0:3], sim._frame[3] = rotation, position
        transform = sim.body_transform()
        corners = sim._body_corners @ transform[:3, :3].T + transform[:3, 3]
        distance, _ = distances_to_boxes(corners, sim.terrain.boxes, sim.terrain.candidates(corners))
        expected = bool((distance < 0.0).any())
        assert sim.body_touches_ground() == expected
        inside += expected
    assert 20 < inside < 380
