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
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.model.robot import LEG_NAMES, build_urdf, foot_offset, joint_names
from testbed.model.truth import Truth
from testbed.world.contact import FootContacts, make_contact_model
from testbed.world.records import raw
from testbed.world.state import ROOT_DOFS, ROOT_TRANSLATION, read_out_record
from testbed.world.terrain import Terrain

INITIAL_CLEARANCE = 0.001   # m, feet start this far above the ground and settle onto it
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
        self._apply_contact, self._read_out_state = self.contact.apply, self.contact.read_state
        self._update_contact = self.contact.update
        # DART's clock, kept here: World.step adds the time step to it, and asking DART costs a
        # binding call twice per step.
        self._time = self.world.getTime()
        self._read_out = raw(read_out_record(self.dt, self.geometry))
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
        centre of mass; the feet follow by eq. 2, all in one compiled call (`state.read_out`, which the
        contact model may extend: ContactModel.read_state). Then the contact model's update on that state."""
        positions, velocities, com = self._get_positions(), self._get_velocities(), self._get_com()
        state, finite, up = self._read_out_state(positions, velocities, self._read_out)
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


@njit(cache=True)
def servo_speeds(targets, positions, gain, limit, out) -> None:
    """The servos' speed commands into `out`: proportional to the position error, saturated at the
    no-load speed."""
    for i in range(len(targets)):
        out[i] = min(max(gain * (targets[i] - positions[i]), -limit), limit)
