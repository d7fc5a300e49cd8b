"""The DART world: robot from its URDF, terrain from boxes, a contact model, servos.

`Simulation.step(joint_targets)` advances one physics step; `Simulation.truth()` reads the ground
truth. The loop that calls them (sensors, estimator, controller) lives in `testbed.runtime.runner`.
"""

from __future__ import annotations

import math

import dartpy as dart
import numpy as np
from numba import njit

from testbed.model.errors import SimulationDiverged
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance, world_feet_arrays
from testbed.model.robot import LEG_NAMES, build_urdf, foot_offset, joint_names
from testbed.model.truth import Truth
from testbed.world.contact import FootContacts, make_contact_model
from testbed.world.records import one_record
from testbed.world.terrain import Terrain

INITIAL_CLEARANCE = 0.001   # m, feet start this far above the ground and settle onto it
# DART's generalized coordinates: the root FreeJoint's six (rotation vector, then translation; its
# rates: angular, then linear velocity), then the joints' eighteen. DART's spatial velocities (twists)
# hold the angular part, then the linear one.
ROOT_ROTATION, ROOT_TRANSLATION, ROOT_DOFS = slice(0, 3), slice(3, 6), 6
ANGULAR, LINEAR = slice(0, 3), slice(3, 6)
FALL_TILT = np.radians(45.0)


def load_robot(urdf: str) -> dart.dynamics.Skeleton:
    loader = dart.utils.DartLoader()
    options = dart.utils.DartLoaderOptions()
    options.mDefaultRootJointType = dart.utils.DartLoaderRootJointType.FLOATING
    loader.setOptions(options)
    skeleton = loader.parseSkeletonString(urdf, "file:///hexapod/")
    if skeleton is None:
        raise RuntimeError("DART could not parse the generated URDF")
    return skeleton


def build_terrain_skeleton(terrain: Terrain, friction: float) -> dart.dynamics.Skeleton:
    skeleton = dart.dynamics.Skeleton("terrain")
    _, body = skeleton.createWeldJointAndBodyNodePair()
    boxes = terrain.boxes
    for center, half, rotation in zip(boxes.centers, boxes.half_extents, boxes.rotations):
        node = body.createShapeNode(dart.dynamics.BoxShape(2.0 * half))
        node.setRelativeTransform(dart.math.Isometry3(rotation, center))
        node.createVisualAspect()
        node.createCollisionAspect()
        node.createDynamicsAspect().setFrictionCoeff(friction)
    skeleton.setMobile(False)
    return skeleton


class Simulation:
    """One robot on one terrain, stepping at config.run.time_step, with the contact model that
    config.run.contact names (`testbed.world.contact.CONTACT_MODELS`)."""

    def __init__(self, config, terrain: Terrain):
        self.config = config
        self.terrain = terrain
        self.geometry = LegGeometry.from_config(config.robot)
        self.dt = config.run.time_step
        self.urdf = build_urdf(config.robot)
        self.world = dart.simulation.World()
        self.world.setTimeStep(self.dt)
        self.world.setGravity([0.0, 0.0, -config.run.gravity])
        deactivation = self.world.getDeactivationOptions()
        deactivation.mEnabled = False   # sleeping bodies report zero contact force
        self.world.setDeactivationOptions(deactivation)
        self.robot = load_robot(self.urdf)
        self.body = self.robot.getBodyNode("body")
        self.tibias = [self.robot.getBodyNode(f"{leg}_tibia") for leg in LEG_NAMES]
        self.joints = [self.robot.getJoint(name) for name in joint_names()]
        self.foot_offset = foot_offset(config.robot)
        self.mass = self.robot.getMass()
        self._check_root_joint()
        self._setup_servos()
        self.contact = make_contact_model(config.run.contact, config, terrain)
        self._add_robot_to_world()
        self.standing_targets = self._place_robot()
        self._commands = np.zeros(self.robot.getNumDofs())
        self._joint_commands = self._commands[ROOT_DOFS:]
        self._servo_gain = float(config.robot.servo_gain)
        self._servo_limit = float(config.robot.servo_speed_limit)
        # The binding calls of every step, looked up once.
        self._get_positions, self._get_velocities = self.robot.getPositions, self.robot.getVelocities
        self._get_com, self._set_commands = self.robot.getCOM, self.robot.setCommands
        self._world_step = self.world.step
        self._apply_contact, self._update_contact = self.contact.apply, self.contact.update
        # DART's clock, kept here: World.step adds the time step to it, and asking DART costs a
        # binding call twice per step.
        self._time = self.world.getTime()
        self._read_out_record = read_out_record(self.dt, self.geometry)
        self._read_state()

    # ----------------------------------------------------------------- set-up
    def _check_root_joint(self) -> None:
        """The state read-out computes the body's pose and twist from the first six coordinates
        (`free_joint_transform`): that holds for a FreeJoint to the world with identity offsets."""
        joint, identity = self.body.getParentJoint(), np.eye(4)
        if (joint.getType() != "FreeJoint" or self.body.getParentBodyNode() is not None
                or joint.getIndexInSkeleton(0) != 0
                or not np.array_equal(joint.getTransformFromParentBodyNode().matrix(), identity)
                or not np.array_equal(joint.getTransformFromChildBodyNode().matrix(), identity)):
            raise RuntimeError("the robot's body must hang from the world on a FreeJoint with identity offsets")

    def _setup_servos(self) -> None:
        # A DC servo's torque falls linearly from stall to zero at no-load speed: the motor's
        # back-EMF damping is stall torque / no-load speed (0.43 N m s/rad for the MX-28). DART
        # applies joint damping implicitly. Without it a loaded middle leg, whose contact spikes
        # exceed the servo torque, chattered on the ground and slid at 0.58 m/s through its stance.
        damping = self.config.robot.servo_torque_limit / self.config.robot.servo_speed_limit
        for joint in self.joints:
            joint.setActuatorType(dart.dynamics.ActuatorType.SERVO)
            joint.setLimitEnforcement(True)
            joint.setDampingCoefficient(0, damping)

    def _add_robot_to_world(self) -> None:
        """The robot into DART's world after the contact model's set-up. A model that does not use
        DART's collisions has the robot's shapes taken out of DART's collision group: DART then
        skips updating and testing them every step."""
        collides = self.contact.dart_collisions
        if not collides:
            for index in range(self.robot.getNumBodyNodes()):
                self.robot.getBodyNode(index).setCollidable(False)
        self.contact.attach(self)
        self.world.addSkeleton(self.robot)
        if not collides:
            self.world.getConstraintSolver().getCollisionGroup().removeShapeFramesOf(self.robot)

    def add_terrain_to_world(self, friction: float) -> None:
        """The terrain's boxes as a DART skeleton with the friction coefficient `friction`, for a
        contact model that lets DART collide the robot with it."""
        self.world.addSkeleton(build_terrain_skeleton(self.terrain, friction))

    def _place_robot(self) -> np.ndarray:
        """Body level at the nominal height over the ground under it, each foot just above its ground."""
        robot = self.config.robot
        ground = float(self.terrain.height(np.zeros((1, 2)))[0])
        body_z = ground + robot.stance_height
        feet = nominal_stance(self.geometry, robot.stance_radius, robot.stance_height, robot.foot_radius)
        world_z = self._ground_clearing_height(feet[:, :2], robot.foot_radius) + INITIAL_CLEARANCE
        feet[:, 2] = world_z - body_z
        q = inverse_kinematics_all(self.geometry, feet)
        positions = np.zeros(self.robot.getNumDofs())
        positions[ROOT_TRANSLATION] = [0.0, 0.0, body_z]
        positions[ROOT_DOFS:] = q
        self.robot.setPositions(positions)
        self.robot.setVelocities(np.zeros_like(positions))
        return q

    def _ground_clearing_height(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """Height of foot-sphere centres above `xy` that clear the ground under the whole sphere
        (on rough ground a neighbouring block may stand higher than the one under the centre)."""
        angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
        ring = np.column_stack([np.cos(angles), np.sin(angles)]) * radius
        stencil = np.concatenate([np.zeros((1, 2)), ring])
        points = (xy[:, None, :] + stencil[None]).reshape(-1, 2)
        highest = self.terrain.height(points).reshape(len(xy), -1).max(axis=1)
        return highest + radius / self.terrain.normal(xy)[:, 2]

    # ----------------------------------------------------------------- stepping
    @property
    def time(self) -> float:
        return self._time

    def joint_positions(self) -> np.ndarray:
        return self.robot.getPositions()[ROOT_DOFS:]

    def step(self, joint_targets: np.ndarray) -> None:
        """One physics step with the servos driving towards `joint_targets` (18,) rad."""
        servo_speeds(np.asarray(joint_targets, dtype=float), self._truth.joint_positions, self._servo_gain,
                     self._servo_limit, self._joint_commands)
        self._set_commands(self._commands)   # world.step() clears commands: set them every step
        self._apply_contact()
        self._world_step()
        self._time += self.dt
        self._read_state()

    def _read_state(self) -> None:
        """Everything the truth and the contact model need, read from DART once per step: the joint
        coordinates and rates (the body's pose and twist follow from the root FreeJoint's) and the
        centre of mass; the feet follow by eq. 2, all in one compiled call (`_read_out`). Then the
        contact model's update on that state."""
        positions, velocities, com = self._get_positions(), self._get_velocities(), self._get_com()
        state, finite, up = _read_out(positions, velocities, self._read_out_record)
        if not finite:
            raise SimulationDiverged(f"simulation state became non-finite at t = {self.time:.3f} s")
        self._state, self._up = state, up
        contacts = self._contacts = self._update_contact(state)
        # Views of the read-out's one record (a new one at each step): numba hands back each
        # returned array for more than a view costs.
        self._truth = Truth(self._time, state["position"], state["rotation"], state["linear_velocity"],
                            state["angular_velocity"], state["linear_acceleration"], state["angular_acceleration"],
                            positions[ROOT_DOFS:], velocities[ROOT_DOFS:], state["foot_centers"], contacts.forces,
                            contacts.normal_forces, contacts.in_contact, com)
        self._quaternion = state["quaternion"]

    @property
    def cone_corrections(self) -> int:
        """Contact forces the contact model projected back onto the friction cone."""
        return self.contact.cone_corrections

    # ----------------------------------------------------------------- reading
    def state(self) -> np.ndarray:
        """The latest read-out: a 0-d STATE record array (new at each step; not to be modified)."""
        return self._state

    def body_transform(self) -> np.ndarray:
        transform = np.eye(4)
        transform[:3, :3], transform[:3, 3] = self._state["rotation"], self._state["position"]
        return transform

    def body_quaternion(self) -> np.ndarray:
        """world_from_body as (x, y, z, w): new at each step and shared, like the truth's arrays
        (not to be modified)."""
        return self._quaternion

    def truth(self) -> Truth:
        # Built by the state read-out: every array in it is new at each step, and may be shared.
        return self._truth

    def contacts(self) -> FootContacts:
        return self._contacts

    def body_touches_ground(self) -> bool:
        return self.contact.body_touches_ground(self._state)

    def body_tilt(self) -> float:
        """Angle between the body's z axis and the vertical, rad."""
        return math.acos(min(max(self._up, -1.0), 1.0))


# The state read-out's record (`_read_out`), one 0-d array per step: the body's pose, its
# world-frame velocities and their finite differences over the step, its attitude as (x, y, z, w),
# and the feet and tibias by eq. 2 (kinematics.WorldFeet's arrays).
LEGS = 6
STATE = np.dtype([("rotation", np.float64, (3, 3)), ("position", np.float64, (3,)),
                  ("linear_velocity", np.float64, (3,)), ("angular_velocity", np.float64, (3,)),
                  ("linear_acceleration", np.float64, (3,)), ("angular_acceleration", np.float64, (3,)),
                  ("quaternion", np.float64, (4,)), ("foot_centers", np.float64, (LEGS, 3)),
                  ("foot_velocities", np.float64, (LEGS, 3)), ("tibia_spins", np.float64, (LEGS, 3)),
                  ("tibia_rotations", np.float64, (LEGS, 3, 3)), ("tibia_origins", np.float64, (LEGS, 3))])
# What the read-out needs besides DART's coordinates: the time step, the leg geometry, and the
# body's velocities one step earlier (updated in place).
READ_OUT = np.dtype([("dt", np.float64), ("femur", np.float64), ("tibia", np.float64),
                     ("base_angle", np.float64, (LEGS,)), ("base_distance", np.float64, (LEGS,)),
                     ("previous_linear_velocity", np.float64, (3,)), ("previous_angular_velocity", np.float64, (3,))])


def read_out_record(dt: float, geometry: LegGeometry) -> np.ndarray:
    """A one-element READ_OUT array for a body at rest."""
    return one_record(READ_OUT, dt=dt, femur=geometry.femur, tibia=geometry.tibia, base_angle=geometry.base_angle,
                      base_distance=geometry.base_distance, previous_linear_velocity=0.0, previous_angular_velocity=0.0)


@njit(cache=True)
def _read_out(positions, velocities, read_out):
    """The 0-d STATE array of DART's coordinates and rates `positions`, `velocities` (the root
    FreeJoint's first, then the joints'), with the READ_OUT record `read_out` (its previous
    velocities updated in place); whether every coordinate and rate is finite; and the body's z
    axis's vertical component (world_from_body[2, 2])."""
    settings = read_out[0]
    state = np.zeros((), STATE)
    out = state[()]
    transform = free_joint_transform(positions)
    rotation = transform[:3, :3]
    twist = free_joint_twist(rotation, velocities)
    body_angular, body_linear = twist[ANGULAR], twist[LINEAR]
    for i in range(3):
        angular = rotation[i, 0] * body_angular[0] + rotation[i, 1] * body_angular[1] + rotation[i, 2] * body_angular[2]
        linear = rotation[i, 0] * body_linear[0] + rotation[i, 1] * body_linear[1] + rotation[i, 2] * body_linear[2]
        # Finite differences of the body velocity over the step: DART's own accelerations miss the
        # servo and contact constraint impulses, which are part of what an accelerometer feels.
        out.linear_acceleration[i] = (linear - settings.previous_linear_velocity[i]) / settings.dt
        out.angular_acceleration[i] = (angular - settings.previous_angular_velocity[i]) / settings.dt
        out.linear_velocity[i], out.angular_velocity[i], out.position[i] = linear, angular, transform[i, 3]
        for j in range(3):
            out.rotation[i, j] = rotation[i, j]
    settings.previous_linear_velocity[:] = out.linear_velocity
    settings.previous_angular_velocity[:] = out.angular_velocity
    out.quaternion[:] = rotation_to_quaternion(rotation)
    if not (np.isfinite(positions).all() and np.isfinite(velocities).all()):
        return state, False, rotation[2, 2]
    centers, feet_velocities, spins, rotations, origins = world_feet_arrays(
        rotation, out.position, out.angular_velocity, out.linear_velocity, positions[ROOT_DOFS:],
        velocities[ROOT_DOFS:], settings.base_angle, settings.base_distance, settings.femur, settings.tibia)
    out.foot_centers[:] = centers
    out.foot_velocities[:] = feet_velocities
    out.tibia_spins[:] = spins
    out.tibia_rotations[:] = rotations
    out.tibia_origins[:] = origins
    return state, True, rotation[2, 2]


# The body's pose and twist from the root FreeJoint's coordinates, as DART computes them (the
# read-out asks no per-body getter of DART). It holds for a FreeJoint to the world with identity
# offsets (`Simulation._check_root_joint`); tests/testbed/test_simulation_state.py compares them
# with DART's getters.
EXP_MAP_SMALL_ANGLE = 1e-3      # rad: DART's expMapRot switches to its second-order series below this


@njit(cache=True)
def free_joint_transform(positions):
    """(4, 4) world_from_body of the root FreeJoint's coordinates (rotation vector, translation): DART's
    math::expMapRot, R = I + sin(t)/t [q]x + (1 - cos(t))/t^2 [q]x^2 (I + [q]x + [q]x^2 / 2 below the
    small angle), in Eigen's order of operations; the translation gains DART's + 0.0 (-0.0 becomes 0.0)."""
    rotation_vector, translation = positions[ROOT_ROTATION], positions[ROOT_TRANSLATION]
    q0, q1, q2 = rotation_vector[0], rotation_vector[1], rotation_vector[2]
    theta = math.sqrt((q0 * q0 + q1 * q1) + q2 * q2)
    if theta < EXP_MAP_SMALL_ANGLE:
        first, second = 1.0, 0.5
    else:
        first, second = math.sin(theta) / theta, (1.0 - math.cos(theta)) / (theta * theta)
    hat = np.array([[0.0, -q2, q1], [q2, 0.0, -q0], [-q1, q0, 0.0]])
    transform = np.zeros((4, 4))
    for i in range(3):
        for j in range(3):
            squared = (hat[i, 0] * hat[0, j] + hat[i, 1] * hat[1, j]) + hat[i, 2] * hat[2, j]
            transform[i, j] = ((1.0 if i == j else 0.0) + first * hat[i, j]) + second * squared
        transform[i, 3] = translation[i] + 0.0
    transform[3, 3] = 1.0
    return transform


@njit(cache=True)
def free_joint_twist(rotation, velocities):
    """(6,) body-frame spatial velocity (angular, linear) of the root FreeJoint's rates (world frame):
    R^T w and R^T v, summed onto 0.0 as DART accumulates them onto a zero twist (-0.0 becomes 0.0)."""
    twist = np.empty(6)
    for part in (ANGULAR, LINEAR):
        rate, body = velocities[part], twist[part]
        for i in range(3):
            body[i] = 0.0 + ((rotation[0, i] * rate[0] + rotation[1, i] * rate[1]) + rotation[2, i] * rate[2])
    return twist


@njit(cache=True)
def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of a rotation matrix by Eigen's algorithm, the one DART's quaternion() runs (same
    branch, hence the same sign)."""
    m = rotation
    q = np.empty(4)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        t = math.sqrt(trace + 1.0)
        q[3] = 0.5 * t
        t = 0.5 / t
        q[0], q[1], q[2] = (m[2, 1] - m[1, 2]) * t, (m[0, 2] - m[2, 0]) * t, (m[1, 0] - m[0, 1]) * t
        return q
    i = 0
    if m[1, 1] > m[0, 0]:
        i = 1
    if m[2, 2] > m[i, i]:
        i = 2
    j, k = (i + 1) % 3, (i + 2) % 3
    t = math.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
    q[i] = 0.5 * t
    t = 0.5 / t
    q[3] = (m[k, j] - m[j, k]) * t
    q[j] = (m[j, i] + m[i, j]) * t
    q[k] = (m[k, i] + m[i, k]) * t
    return q


@njit(cache=True)
def servo_speeds(targets, positions, gain, limit, out) -> None:
    """The servos' speed commands into `out`: proportional to the position error, saturated at the
    no-load speed."""
    for i in range(len(targets)):
        out[i] = min(max(gain * (targets[i] - positions[i]), -limit), limit)
