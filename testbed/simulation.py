"""The DART world: robot from its URDF, terrain from boxes, one of two contact models, servos.

`Simulation.step(joint_targets)` advances one physics step; `Simulation.truth()` reads the ground
truth. The loop that calls them (sensors, estimator, controller) lives in `testbed.runner`.
"""

from __future__ import annotations

import dartpy as dart
import numpy as np

from testbed.config import Config
from testbed.contact import CompliantContact, FootContacts
from testbed.errors import SimulationDiverged
from testbed.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.robot import LEG_NAMES, build_urdf, foot_offset, joint_names
from testbed.terrain import Terrain
from testbed.truth import Truth

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
    """One robot on one terrain, stepping at config.run.time_step."""

    def __init__(self, config: Config, terrain: Terrain):
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
        self._setup_servos()
        self.contact_model = config.run.contact
        self._setup_contact()
        self.world.addSkeleton(self.robot)
        self.standing_targets = self._place_robot()
        self._last_velocity = np.zeros(3)
        self._last_angular_velocity = np.zeros(3)
        self._acceleration = np.zeros(3)
        self._angular_acceleration = np.zeros(3)
        self._contacts = FootContacts.none()
        self._foot_state_time = -1.0
        self._foot_state = None
        self.cone_corrections = 0          # DART contact forces projected back onto the cone
        self.worst_cone_ratio = 1.0        # worst |F_t| / (mu F_n) that DART reported

    # ----------------------------------------------------------------- set-up
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
        return self.world.getTime()

    def joint_positions(self) -> np.ndarray:
        return self.robot.getPositions()[6:]

    def step(self, joint_targets: np.ndarray) -> None:
        """One physics step with the servos driving towards `joint_targets` (18,) rad."""
        robot = self.config.robot
        q = self.robot.getPositions()[6:]
        speed = np.clip(robot.servo_gain * (joint_targets - q), -robot.servo_speed_limit, robot.servo_speed_limit)
        commands = np.zeros(self.robot.getNumDofs())
        commands[6:] = speed
        self.robot.setCommands(commands)   # world.step() clears commands: set them every step
        if self.contact_model == "compliant":
            self._apply_compliant_contact()
        self.world.step()
        if self.contact_model == "dart":
            self._contacts = self._read_dart_contacts()
        self._update_accelerations()

    def _foot_states(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tibia transforms, foot centres, foot-centre velocities and tibia spins (world); read
        once per simulation time: the truth after a step and the contact before the next share it."""
        if self._foot_state_time == self.world.getTime():
            return self._foot_state
        transforms = np.array([tibia.getWorldTransform().matrix() for tibia in self.tibias])
        centers = transforms[:, :3, :3] @ self.foot_offset + transforms[:, :3, 3]
        velocities = np.array([tibia.getLinearVelocity(self.foot_offset) for tibia in self.tibias])
        spins = np.array([tibia.getAngularVelocity() for tibia in self.tibias])
        self._foot_state_time = self.world.getTime()
        self._foot_state = (transforms, centers, velocities, spins)
        return self._foot_state

    def _apply_compliant_contact(self) -> None:
        transforms, centers, velocities, spins = self._foot_states()
        contacts = self.compliant.compute(centers, velocities, spins)
        for leg in np.flatnonzero(contacts.in_contact):
            tibia, transform = self.tibias[leg], transforms[leg]
            offset = transform[:3, :3].T @ (contacts.points[leg] - transform[:3, 3])
            tibia.addExtForce(contacts.forces[leg], offset, False, True)
        self._contacts = contacts

    def _read_dart_contacts(self) -> FootContacts:
        forces = np.zeros((6, 3))
        normals = np.zeros((6, 3))
        points = np.zeros((6, 3))
        counts = np.zeros(6)
        self._body_touches = False
        for contact in self.world.getLastCollisionResult().getContacts():
            names = (contact.collisionObject1.getShapeFrame().getName(),
                     contact.collisionObject2.getShapeFrame().getName())
            for side, name in enumerate(names):
                leg = self.foot_shape_leg.get(name)
                if leg is None:
                    if name.startswith("body"):
                        self._body_touches = True
                    continue
                # contact.force acts on collisionObject1 and its normal points from 2 towards 1.
                sign = 1.0 if side == 0 else -1.0
                forces[leg] += sign * np.asarray(contact.force)
                normals[leg] += sign * np.asarray(contact.normal)
                points[leg] += np.asarray(contact.point)
                counts[leg] += 1
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

    def _update_accelerations(self) -> None:
        # Finite differences of the body velocity over the step: DART's own accelerations miss the
        # servo and contact constraint impulses, which are part of what an accelerometer feels.
        velocity = np.asarray(self.body.getLinearVelocity())
        angular = np.asarray(self.body.getAngularVelocity())
        if not (np.all(np.isfinite(velocity)) and np.all(np.isfinite(angular))
                and np.all(np.isfinite(self.robot.getPositions()))):
            raise SimulationDiverged(f"simulation state became non-finite at t = {self.time:.3f} s")
        self._acceleration = (velocity - self._last_velocity) / self.dt
        self._angular_acceleration = (angular - self._last_angular_velocity) / self.dt
        self._last_velocity = velocity
        self._last_angular_velocity = angular

    # ----------------------------------------------------------------- reading
    def body_transform(self) -> np.ndarray:
        return self.body.getWorldTransform().matrix()

    def body_quaternion(self) -> np.ndarray:
        """world_from_body as (x, y, z, w), from DART directly (a tenth of scipy's cost per call)."""
        w, x, y, z = self.body.getWorldTransform().quaternion().wxyz()
        return np.array([x, y, z, w])

    def truth(self) -> Truth:
        transform = self.body_transform()
        positions = self.robot.getPositions()
        velocities = self.robot.getVelocities()
        _, centers, _, _ = self._foot_states()
        contacts = self._contacts
        return Truth(
            t=self.time,
            body_position=transform[:3, 3].copy(),
            body_rotation=transform[:3, :3].copy(),
            body_linear_velocity=self._last_velocity.copy(),
            body_angular_velocity=self._last_angular_velocity.copy(),
            body_linear_acceleration=self._acceleration.copy(),
            body_angular_acceleration=self._angular_acceleration.copy(),
            joint_positions=positions[6:].copy(),
            joint_velocities=velocities[6:].copy(),
            foot_positions=centers,
            foot_forces=contacts.forces.copy(),
            foot_normal_forces=contacts.normal_forces.copy(),
            foot_contact=contacts.in_contact.copy(),
            com_position=np.asarray(self.robot.getCOM()).copy(),
        )

    def contacts(self) -> FootContacts:
        return self._contacts

    def body_touches_ground(self) -> bool:
        if self.contact_model == "dart":
            return bool(getattr(self, "_body_touches", False))
        half = np.asarray(self.config.robot.body_size) / 2
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        transform = self.body_transform()
        world_corners = corners @ transform[:3, :3].T + transform[:3, 3]
        distance, _ = self.terrain.closest(world_corners)
        return bool(np.any(distance < 0.0))

    def body_tilt(self) -> float:
        """Angle between the body's z axis and the vertical, rad."""
        return float(np.arccos(np.clip(self.body_transform()[2, 2], -1.0, 1.0)))
