"""The DART world: robot from its URDF, terrain from boxes, one of two contact models, servos.

`Simulation.step(joint_targets)` advances one physics step; `Simulation.truth()` reads the ground
truth. The loop that calls them (sensors, estimator, controller) lives in `testbed.runtime.runner`.
"""

from __future__ import annotations

import math

import dartpy as dart
import numpy as np
from numba import njit
from testbed.world.contact import CompliantContact, FootContacts, hard_finger_into
from testbed.model.errors import SimulationDiverged
from testbed.model.kinematics import (LegGeometry, inverse_kinematics_all, nominal_stance, rows_times_matrix,
                                world_feet_arrays)
from testbed.model.robot import LEG_NAMES, build_urdf, foot_offset, joint_names
from testbed.world.terrain import Terrain, candidates_by_rule, closest_distance, distances_to_boxes
from testbed.model.truth import Truth

INITIAL_CLEARANCE = 0.001   # m, feet start this far above the ground and settle onto it
BODY = -1                   # what Simulation._collision_object_leg answers for the body's shapes
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
    """One robot on one terrain, stepping at config.run.time_step."""

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
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        self._body_corners = signs * np.asarray(config.robot.body_size) / 2
        self.mass = self.robot.getMass()
        self._check_root_joint()
        self._setup_servos()
        self.contact_model = config.run.contact
        self._compliant = self.contact_model == "compliant"
        self._setup_contact()
        self.world.addSkeleton(self.robot)
        if self.contact_model == "compliant":
            # Nothing in DART's world collides (the compliant model applies the contact forces):
            # without the robot's shapes in its collision group, DART skips updating and testing
            # them every step (~3 us of its ~50 us step; the motion is the same to the bit).
            self.world.getConstraintSolver().getCollisionGroup().removeShapeFramesOf(self.robot)
        self.standing_targets = self._place_robot()
        self._commands = np.zeros(self.robot.getNumDofs())
        self._joint_commands = self._commands[6:]
        self._servo_gain = float(config.robot.servo_gain)
        self._servo_limit = float(config.robot.servo_speed_limit)
        # The binding calls of every step, looked up once.
        self._get_positions, self._get_velocities = self.robot.getPositions, self.robot.getVelocities
        self._get_com, self._set_commands = self.robot.getCOM, self.robot.setCommands
        self._world_step = self.world.step
        # DART's clock, kept here: World.step adds the time step to it (tested equal bit for bit),
        # and asking DART costs a binding call (~1 us in the run loop) twice per step.
        self._time = self.world.getTime()
        self._setup_read_out()
        self._read_state()
        self.cone_corrections = 0          # DART contact forces projected back onto the cone
        self.worst_cone_ratio = 1.0        # worst |F_t| / (mu F_n) that DART reported

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

    def _setup_contact(self) -> None:
        friction = self.config.contact.friction
        if self.contact_model == "compliant":
            for index in range(self.robot.getNumBodyNodes()):
                self.robot.getBodyNode(index).setCollidable(False)
            self.compliant = CompliantContact(self.config.contact, self.terrain, self.config.robot.foot_radius)
            return
        # DART's boxed LCP bounds each of two friction directions by mu * F_n: a pyramid whose
        # corners reach sqrt(2) * mu * F_n. Giving it mu / sqrt(2) inscribes the pyramid in the
        # true cone, so no contact force it returns leaves the friction cone.
        pyramid = friction / np.sqrt(2.0)
        self.world.addSkeleton(build_terrain_skeleton(self.terrain, pyramid))
        for tibia in self.tibias:
            for node in tibia.getShapeNodes():
                if node.hasDynamicsAspect():
                    node.getDynamicsAspect().setFrictionCoeff(pyramid)
                    node.getDynamicsAspect().setRestitutionCoeff(0.0)
        self.foot_shape_leg = {tibia.getShapeNodes()[-1].getName(): leg for leg, tibia in enumerate(self.tibias)}
        self._collision_legs: dict[object, int | None] = {}

    def _setup_read_out(self) -> None:
        """What the state read-out kernel (`_read_out`) needs besides DART's coordinates, packed once;
        with the compliant contact, the kernel also computes the next step's contact forces."""
        geometry = self.geometry
        contact_parameters = self.compliant.parameters if self._compliant else np.zeros(CONTACT_PARAMETERS)
        self._read_out_constants = np.concatenate([[self.dt, geometry.femur, geometry.tibia], geometry.base_angle,
                                                   geometry.base_distance, contact_parameters])
        # The kernel's state between steps and its outputs besides the frame, in one array (numba
        # unboxes each argument): the body's velocities one step earlier, the sticking anchors of
        # the compliant contact, and the forces the next step applies and their points in the
        # tibias' frames.
        state = np.zeros((STATE_ROWS, 3))
        if self._compliant:
            state[ANCHORS:ANCHORS + 6] = self.compliant.anchors
            self.compliant.anchors = state[ANCHORS:ANCHORS + 6]
        self._read_out_state = state
        boxes = self.terrain.boxes
        self._boxes = (boxes.centers, boxes.half_extents, boxes.rotations)
        # The terrain's candidate boxes found in the kernels, unless it has a rule of its own.
        self._candidate_rule = self.terrain.candidate_rule()
        self._rule, self._rule_data = self._candidate_rule or (NO_RULE, np.zeros(1))
        self._contact_mode = COMPLIANT_CONTACT if self._compliant and self._candidate_rule else NO_CONTACT
        # Per set of touching feet (bits), the addExtForce calls that apply the kernel's forces.
        self._applied_forces = state[APPLIED_FORCES:APPLIED_FORCES + 6]
        self._applied_offsets = state[APPLIED_OFFSETS:APPLIED_OFFSETS + 6]
        self._applications = tuple(
            tuple((self.tibias[leg].addExtForce, self._applied_forces[leg], self._applied_offsets[leg])
                  for leg in range(6) if bits >> leg & 1) for bits in range(64))
        self._contacts = FootContacts.none()    # the contacts acting in the latest step
        self._pending, self._pending_bits = self._contacts, 0   # the compliant contact of the next step

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
        positions[3:6] = [0.0, 0.0, body_z]
        positions[6:] = q
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
        return self.robot.getPositions()[6:]

    def step(self, joint_targets: np.ndarray) -> None:
        """One physics step with the servos driving towards `joint_targets` (18,) rad."""
        servo_speeds(np.asarray(joint_targets, dtype=float), self._truth.joint_positions, self._servo_gain,
                     self._servo_limit, self._joint_commands)
        self._set_commands(self._commands)   # world.step() clears commands: set them every step
        if self._compliant:
            self._apply_compliant_contact()
        self._world_step()
        self._time += self.dt
        if not self._compliant:
            self._contacts = self._read_dart_contacts()
        self._read_state()

    def _read_state(self) -> None:
        """Everything the truth and the next contact need, read from DART once per step: the joint
        coordinates and rates (the body's pose and twist follow from the root FreeJoint's), the centre
        of mass; the feet follow by eq. 2, and with the compliant contact the forces of the next
        step from them, all in one compiled call (`_read_out`)."""
        positions, velocities, com = self._get_positions(), self._get_velocities(), self._get_com()
        centers, halves, rotations = self._boxes
        frame, bits, up = _read_out(positions, velocities, self._read_out_constants, self._read_out_state,
                                    self._contact_mode, centers, halves, rotations, self._rule, self._rule_data)
        if bits < 0:
            raise SimulationDiverged(f"simulation state became non-finite at t = {self.time:.3f} s")
        self._frame, self._up = frame, up
        contacts = self._contacts
        # Views of the kernel's one array (a new one at each step): numba hands back each returned
        # array for ~0.4 us, a view costs a quarter of that.
        self._truth = Truth(self._time, frame[POSITION], frame[0:3], frame[LINEAR], frame[ANGULAR], frame[LINEAR_RATE],
                            frame[ANGULAR_RATE], positions[6:], velocities[6:], frame[CENTERS:CENTERS + 6],
                            contacts.forces, contacts.normal_forces, contacts.in_contact, com)
        flat = frame.reshape(-1)
        self._quaternion = flat[QUATERNION:QUATERNION + 4]
        if self._compliant:
            if self._candidate_rule is None:
                bits = self._other_candidates_contact(frame, positions, velocities)
            self._pending = FootContacts(frame[FORCES:FORCES + 6], flat[NORMAL_FORCES:NORMAL_FORCES + 6],
                                         frame[NORMALS:NORMALS + 6], frame[POINTS:POINTS + 6], IN_CONTACT[bits])
            self._pending_bits = bits

    def _other_candidates_contact(self, frame: np.ndarray, positions: np.ndarray, velocities: np.ndarray) -> int:
        """The compliant contact on a terrain with its own candidate boxes: asked in Python for the
        feet the kernel read out, then the same model in a second compiled call."""
        candidates = np.ascontiguousarray(self.terrain.candidates(frame[CENTERS:CENTERS + 6]), dtype=np.int64)
        centers, halves, rotations = self._boxes
        return _contact_of_frame(frame, positions, velocities, self._read_out_constants, self._read_out_state, centers,
                                 halves, rotations, candidates)

    def _apply_compliant_contact(self) -> None:
        """The forces the kernel computed from the latest state, on the tibias whose feet touch."""
        for add_force, force, offset in self._applications[self._pending_bits]:
            add_force(force, offset, False, True)
        self._contacts = self._pending

    def _read_dart_contacts(self) -> FootContacts:
        # Sums in Python floats, contact by contact in DART's order: the same additions numpy made on
        # (3,) rows, without a dozen numpy calls per contact.
        forces, normals, points = ([[0.0, 0.0, 0.0] for _ in range(6)] for _ in range(3))
        counts = [0.0] * 6
        self._body_touches = False
        for contact in self.world.getLastCollisionResult().getContacts():
            for sign, collision_object in ((1.0, contact.collisionObject1), (-1.0, contact.collisionObject2)):
                leg = self._collision_object_leg(collision_object)
                if leg is None:
                    continue
                if leg == BODY:
                    self._body_touches = True
                    continue
                # contact.force acts on collisionObject1 and its normal points from 2 towards 1.
                force, normal, point = forces[leg], normals[leg], points[leg]
                for i, (f, n, p) in enumerate(zip(contact.force.tolist(), contact.normal.tolist(),
                                                  contact.point.tolist())):
                    force[i] += sign * f
                    normal[i] += sign * n
                    point[i] += p
                counts[leg] += 1
        return self._foot_contacts(np.array(forces), np.array(normals), np.array(points), np.array(counts))

    def _collision_object_leg(self, collision_object) -> int | None:
        """The leg whose foot `collision_object` is, BODY for the body, None for anything else.
        Asking DART for a shape's name costs ~5 us, so the answer is kept per collision object
        (dartpy hands back the same Python object for the same DART collision object)."""
        try:
            return self._collision_legs[collision_object]
        except KeyError:
            name = collision_object.getShapeFrame().getName()
            leg = self.foot_shape_leg.get(name, BODY if name.startswith("body") else None)
            self._collision_legs[collision_object] = leg
            return leg

    def _foot_contacts(self, forces: np.ndarray, normals: np.ndarray, points: np.ndarray,
                       counts: np.ndarray) -> FootContacts:
        """FootContacts of the feet's summed contact forces, normals and points (`counts` each)."""
        touching = counts > 0
        normals[touching] /= np.linalg.norm(normals[touching], axis=1)[:, None]
        points[touching] /= counts[touching][:, None]
        normal_forces = np.maximum(np.einsum("ij,ij->i", forces, normals), 0.0)
        forces = self._verify_friction_cone(forces, normals, normal_forces, touching)
        return FootContacts(forces, normal_forces, normals, points, touching)

    def _verify_friction_cone(self, forces, normals, normal_forces, touching) -> np.ndarray:
        """DART's reported contact forces overshoot the friction cone in touch-down transients
        (seen up to 1.2 mu F_n) although its LCP bounds each friction direction correctly while
        sliding. Report them projected onto the cone, and count every projection."""
        tangential = forces - normal_forces[:, None] * normals
        magnitude = np.linalg.norm(tangential, axis=1)
        limit = self.config.contact.friction * normal_forces
        over = touching & (magnitude > limit * (1 + 1e-9) + 1e-9)
        if not over.any():
            return forces
        self.cone_corrections += int(over.sum())
        self.worst_cone_ratio = max(self.worst_cone_ratio, float(np.max(magnitude[over] / np.maximum(limit[over], 1e-12))))
        scale = np.where(over, limit / np.maximum(magnitude, 1e-12), 1.0)
        return normal_forces[:, None] * normals + tangential * scale[:, None]

    # ----------------------------------------------------------------- reading
    def body_transform(self) -> np.ndarray:
        transform = np.eye(4)
        transform[:3, :3], transform[:3, 3] = self._frame[0:3], self._frame[POSITION]
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
        if self.contact_model == "dart":
            return bool(getattr(self, "_body_touches", False))
        frame = self._frame
        if self._candidate_rule is None:
            world_corners = self._body_corners @ frame[0:3].T + frame[POSITION]
            distance, _ = distances_to_boxes(world_corners, self.terrain.boxes, self.terrain.candidates(world_corners))
            return bool((distance < 0.0).any())
        centers, halves, rotations = self._boxes
        return _corners_in_ground(self._body_corners, frame, centers, halves, rotations, self._rule, self._rule_data)

    def body_tilt(self) -> float:
        """Angle between the body's z axis and the vertical, rad."""
        return math.acos(min(max(self._up, -1.0), 1.0))


# Rows of the state read-out's frame (`_read_out`), an (FRAME_ROWS, 3) array: the body's rotation
# (rows 0-2) and position, velocities and their finite differences, the foot centres, and the compliant
# contact's forces, normals and points; its flat view holds the normal forces and the quaternion.
POSITION, LINEAR, ANGULAR, LINEAR_RATE, ANGULAR_RATE = 3, 4, 5, 6, 7
CENTERS, FORCES, NORMALS, POINTS = 8, 14, 20, 26
NORMAL_FORCES, QUATERNION = 3 * 32, 3 * 34      # flat indices
FRAME_ROWS = 36
NO_CONTACT, COMPLIANT_CONTACT = 0, 1     # what the state read-out computes besides the state
NO_RULE = -1                            # a terrain's candidate boxes found in Python (Terrain.candidate_rule)
# Rows of the read-out's state array (`Simulation._read_out_state`), (STATE_ROWS, 3)
PREVIOUS_LINEAR, PREVIOUS_ANGULAR, ANCHORS, APPLIED_FORCES, APPLIED_OFFSETS = 0, 1, 2, 8, 14
STATE_ROWS = 20
CONTACT_PARAMETERS = 7                  # at the end of the read-out's constants: CompliantContact.parameters


def _contact_flags() -> tuple[np.ndarray, ...]:
    """The (6,) bool contact flags of each set of touching feet (bits), shared by the steps that
    have it: read-only."""
    flags = []
    for bits in range(64):
        flag = np.array([(bits >> leg) & 1 == 1 for leg in range(6)])
        flag.flags.writeable = False
        flags.append(flag)
    return tuple(flags)


IN_CONTACT = _contact_flags()


# The state read-out is compiled with numba: it is a few dozen scalar operations per leg, which
# numpy (and DART's per-body getters, ~6 us a call) made a tenth of the whole run loop. The
# compliant contact of the next step is computed in the same call: it depends only on this state,
# and a second compiled call, with its arguments and its six returned arrays, cost ~5 us a step.
@njit(cache=True)
def _read_out(positions, velocities, constants, state, contact_mode, box_centers, box_halves, box_rotations, rule,
              rule_data):
    """The (FRAME_ROWS, 3) frame of the state (its rows: above): world_from_body, the body's
    world-frame velocities and their finite differences over the step (the `state` rows
    PREVIOUS_LINEAR and PREVIOUS_ANGULAR hold the velocities one step earlier and are updated in
    place), the quaternion, the foot centres by eq. 2; with COMPLIANT_CONTACT also the hard-finger
    contact of the next step (`_contact_into`, on the boxes the terrain's candidate `rule` finds).
    Then the touching feet as bits (leg i: 1 << i), -1 if a coordinate or rate is not finite; and
    world_from_body[2, 2]. `constants`: dt, a2, a3, the six base angles, the six base distances,
    then the contact's parameters."""
    dt, a2, a3, base_angle, base_distance = constants[0], constants[1], constants[2], constants[3:9], constants[9:15]
    frame = np.zeros((FRAME_ROWS, 3))
    transform = free_joint_transform(positions)
    rotation = transform[:3, :3]
    twist = free_joint_twist(rotation, velocities)
    angular, linear = np.empty(3), np.empty(3)
    for i in range(3):
        angular[i] = rotation[i, 0] * twist[0] + rotation[i, 1] * twist[1] + rotation[i, 2] * twist[2]
        linear[i] = rotation[i, 0] * twist[3] + rotation[i, 1] * twist[4] + rotation[i, 2] * twist[5]
    # Finite differences of the body velocity over the step: DART's own accelerations miss the
    # servo and contact constraint impulses, which are part of what an accelerometer feels.
    for i in range(3):
        frame[LINEAR_RATE, i] = (linear[i] - state[PREVIOUS_LINEAR, i]) / dt
        frame[ANGULAR_RATE, i] = (angular[i] - state[PREVIOUS_ANGULAR, i]) / dt
        frame[LINEAR, i], frame[ANGULAR, i], frame[POSITION, i] = linear[i], angular[i], transform[i, 3]
        for j in range(3):
            frame[i, j] = rotation[i, j]
    state[PREVIOUS_LINEAR], state[PREVIOUS_ANGULAR] = linear, angular
    flat = frame.reshape(-1)
    flat[QUATERNION:QUATERNION + 4] = rotation_to_quaternion(rotation)
    if not (np.isfinite(positions).all() and np.isfinite(velocities).all()):
        return frame, -1, rotation[2, 2]
    centers, feet_velocities, spins, rotations, origins = world_feet_arrays(
        rotation, transform[:3, 3], angular, linear, positions[6:], velocities[6:], base_angle, base_distance, a2, a3)
    frame[CENTERS:CENTERS + 6] = centers
    if contact_mode == NO_CONTACT:
        return frame, 0, rotation[2, 2]
    candidates = candidates_by_rule(centers, rule, rule_data)
    bits = _contact_into(frame, centers, feet_velocities, spins, rotations, origins, constants, state, box_centers,
                         box_halves, box_rotations, candidates)
    return frame, bits, rotation[2, 2]


@njit(cache=True)
def _contact_into(frame, centers, feet_velocities, spins, rotations, origins, constants, state, box_centers,
                  box_halves, box_rotations, candidates):
    """The hard-finger contact (contact.hard_finger_into, the parameters at the end of the read-out's
    `constants`, the `state`'s anchors updated in place) into the frame's contact rows; the forces
    of the touching feet and their points in the tibias' frames into the `state`'s APPLIED_FORCES
    and APPLIED_OFFSETS rows. Returns the touching feet as bits."""
    local_points = np.empty((6, 3))
    bits = hard_finger_into(centers, feet_velocities, spins, rotations, origins, state[ANCHORS:ANCHORS + 6],
                            constants[len(constants) - CONTACT_PARAMETERS:], box_centers, box_halves, box_rotations,
                            candidates, frame[FORCES:FORCES + 6], frame.reshape(-1)[NORMAL_FORCES:NORMAL_FORCES + 6],
                            frame[NORMALS:NORMALS + 6], frame[POINTS:POINTS + 6], local_points)
    for leg in range(6):
        if (bits >> leg) & 1:
            for i in range(3):
                state[APPLIED_FORCES + leg, i] = frame[FORCES + leg, i]
                state[APPLIED_OFFSETS + leg, i] = local_points[leg, i]
    return bits


@njit(cache=True)
def _contact_of_frame(frame, positions, velocities, constants, state, box_centers, box_halves, box_rotations, candidates):
    """`_read_out`'s contact with candidate boxes found after it: the feet's motion again from the
    frame's pose and velocities (the same numbers, so the same feet), then the same model."""
    a2, a3, base_angle, base_distance = constants[1], constants[2], constants[3:9], constants[9:15]
    centers, feet_velocities, spins, rotations, origins = world_feet_arrays(
        frame[0:3], frame[POSITION], frame[ANGULAR], frame[LINEAR], positions[6:], velocities[6:], base_angle,
        base_distance, a2, a3)
    return _contact_into(frame, centers, feet_velocities, spins, rotations, origins, constants, state, box_centers,
                         box_halves, box_rotations, candidates)


@njit(cache=True)
def _corners_in_ground(corners, frame, box_centers, box_halves, box_rotations, rule, rule_data):
    """Whether any of the body's `corners` (body frame) lies inside a candidate box of the terrain:
    the corners placed as numpy's `corners @ R.T + p` places them (kinematics.rows_times_matrix), the
    candidates by the terrain's `rule` (Terrain.candidate_rule)."""
    world = rows_times_matrix(corners, frame[0:3].T, np.empty_like(corners))
    for row in range(len(world)):
        for i in range(3):
            world[row, i] += frame[POSITION, i]
    candidates = candidates_by_rule(world, rule, rule_data)
    for row in range(len(world)):
        if closest_distance(world[row], box_centers, box_halves, box_rotations, candidates[row]) < 0.0:
            return True
    return False


# The body's pose and twist from the root FreeJoint's coordinates and rates, as DART computes them
# (tests/testbed/test_simulation_state.py holds them to DART's getters bit for bit): asking DART for
# them costs ~15 us per step in the run loop (two binding calls and an Isometry3 object), this ~0.1 us.
# It holds for a FreeJoint to the world with identity offsets (`Simulation._check_root_joint`).
EXP_MAP_SMALL_ANGLE = 1e-3      # rad: DART's expMapRot switches to its second-order series below this


@njit(cache=True)
def free_joint_transform(positions):
    """(4, 4) world_from_body of positions[0:6] = (rotation vector, translation): DART's
    math::expMapRot, R = I + sin(t)/t [q]x + (1 - cos(t))/t^2 [q]x^2 (I + [q]x + [q]x^2 / 2 below the
    small angle), with Eigen's order of operations; the translation gains DART's + 0.0 (-0.0 becomes 0.0)."""
    q0, q1, q2 = positions[0], positions[1], positions[2]
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
        transform[i, 3] = positions[3 + i] + 0.0
    transform[3, 3] = 1.0
    return transform


@njit(cache=True)
def free_joint_twist(rotation, velocities):
    """(6,) body-frame spatial velocity (angular, linear) of velocities[0:6] (world-frame rates):
    R^T w and R^T v, summed onto 0.0 as DART accumulates them onto a zero twist (-0.0 becomes 0.0)."""
    twist = np.empty(6)
    for i in range(3):
        for start in (0, 3):
            twist[start + i] = 0.0 + ((rotation[0, i] * velocities[start] + rotation[1, i] * velocities[start + 1])
                                      + rotation[2, i] * velocities[start + 2])
    return twist


@njit(cache=True)
def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of a rotation matrix by Eigen's algorithm, the one DART's quaternion() runs (same
    branch and sign, equal to 1e-16). Compiled: scipy's Rotation costs ~20 us a call, DART's ~7 us."""
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
    no-load speed (np.clip's wrapper alone cost more than this whole loop)."""
    for i in range(len(targets)):
        out[i] = min(max(gain * (targets[i] - positions[i]), -limit), limit)
