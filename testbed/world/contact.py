"""Contact models: how the feet and the ground push on each other in the simulation.

A contact model is a `ContactModel` registered in the entry point group `hexapod_testbed.contacts`
(`CONTACT_MODELS`); the simulation builds the one `run.contact` names. The two built-ins:

`compliant` -- the paper's hard-finger contact (section 3.3), applied to DART as external forces
at each foot. Normal force: a nonlinear spring-damper of the indentation d of the foot sphere in
the terrain, Hunt-Crossley form F_n = k d^n (1 + c d') (Hunt & Crossley 1975; n = 1.5 is Hertz's
sphere on a plane), never pulling. The damping vanishes with d, so the force is continuous at
touch-down; the damping factor c d' is bounded to [-1, 1] (at most twice the elastic force): a fast
impact then cannot produce an impulse that an explicit 1 ms step turns unstable on a light tibia.
Tangential force: Coulomb friction, proportional to F_n and opposite to the slip velocity while
sliding. It is regularised with a stick-slip spring (an elasto-plastic bristle, as in Dahl's and
LuGre's models) rather than by a viscous slope around zero slip: a viscous regularisation steep
enough to hold a robot on a slope for seconds is unstable at a 1 ms explicit step, while the
spring holds it exactly and only the force cap mu * F_n decides when the foot slides. The spring's
stretch is the integral of the slip of the sphere's material contact point, v + w x a (a = the
contact point less the centre), not of the geometric point under the centre: its ground anchor
moves by -(w x a) dt each step, so a sphere that rolls without slipping (v = w x r n) feels no
spring, and one that spins in place with its centre held does. The foot rolls as DART's does.

`dart` -- DART's own rigid contact: its collision detection and boxed LCP solver.

The hard-finger law is written once in numpy (`hard_finger`); the per-step model runs the compiled
kernel beside it (`hard_finger_into`) inside the state read-out's call, with its parameters in a
`COMPLIANT` record.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.model.kinematics import WorldFeet
from testbed.model.registry import Registry
from testbed.world.config import ContactConfig
from testbed.world.records import one_record, raw, the_record
from testbed.world.state import READ_OUT, STATE, read_out, read_out_into
from testbed.world.terrain import (BOX, CANDIDATE_RULE, Terrain, candidates_by_rule, closest_distance,
                                   sphere_contact_arrays)

LEGS = 6


class FootContacts(NamedTuple):
    """Contact result for the six feet, world frame (a named tuple: one is built per physics step)."""
    forces: np.ndarray          # (6, 3) N, ground reaction on each foot
    normal_forces: np.ndarray   # (6,) N, along the terrain normal
    normals: np.ndarray         # (6, 3) unit terrain normals at the contacts (zeros where no contact)
    points: np.ndarray          # (6, 3) m, contact points on the foot surface
    in_contact: np.ndarray      # (6,) bool

    @staticmethod
    def none() -> "FootContacts":
        return FootContacts(np.zeros((6, 3)), np.zeros(6), np.zeros((6, 3)), np.zeros((6, 3)), np.zeros(6, bool))


class ContactModel:
    """Base class of every contact model. Built by `from_config(config, terrain)`; the simulation
    then calls `attach(simulation)` once, before the robot joins DART's world, and per physics step
    `apply()` before DART's step, `read_state(...)` after it for the state read-out (a STATE record,
    `Simulation.state()`), and `update(state)`, which answers the contacts that acted during that step."""

    name = "contact"
    dart_collisions = False         # whether DART must detect the robot's collisions itself
    cone_corrections = 0            # contact forces projected back onto the friction cone

    @classmethod
    def from_config(cls, config, terrain: Terrain) -> "ContactModel":
        return cls(config, terrain)

    def __init__(self, config, terrain: Terrain):
        self.config = config
        self.terrain = terrain

    def attach(self, simulation) -> None:
        """Set DART's world up for this model (called before the robot is added to it)."""

    def apply(self) -> None:
        """Act on DART's world before its step."""

    def read_state(self, positions: np.ndarray, velocities: np.ndarray, read_out_raw: np.ndarray
                   ) -> tuple[np.ndarray, bool, float]:
        """The simulation's state read-out (`state.read_out`). A model whose forces follow from the
        state may compute them in the same compiled call, into the STATE record's contact fields."""
        return read_out(positions, velocities, read_out_raw)

    def update(self, state: np.ndarray) -> FootContacts:
        """The contacts that acted during the step just taken."""
        raise NotImplementedError(f"{type(self).__name__} must implement update(state)")

    def body_touches_ground(self, state: np.ndarray) -> bool:
        raise NotImplementedError(f"{type(self).__name__} must implement body_touches_ground(state)")


CONTACT_MODELS = Registry.of_subclasses("contact model", "contacts", ContactModel)


def make_contact_model(spec: str, config, terrain: Terrain) -> ContactModel:
    return CONTACT_MODELS.build(spec, config, terrain)


# ---------------------------------------------------------------- the hard-finger law
def hard_finger(feet: WorldFeet, depth: np.ndarray, normals: np.ndarray, anchors: np.ndarray,
                config: ContactConfig, foot_radius: float, time_step: float) -> tuple[FootContacts, np.ndarray]:
    """The contact forces on feet moving as `feet`, indented `depth` (N,) m into the terrain along
    the unit `normals` (N, 3) (Terrain.sphere_contacts); updates the sticking `anchors` (N, 3, NaN
    rows: no anchor) in place, rolling them with the spheres over `time_step` (s). Also the contact
    points in the tibias' frames, where the forces act."""
    touching = depth > 0.0
    points = feet.centers - foot_radius * normals
    rolling = np.cross(feet.spins, points - feet.centers)       # the material point's speed relative to the centre
    velocity = feet.velocities + rolling                        # of the material contact point
    normal_speed = np.sum(velocity * normals, axis=1)
    damping_factor = np.clip(config.damping * -normal_speed, -1.0, 1.0)
    elastic = config.stiffness * np.where(touching, depth, 0.0) ** config.exponent
    normal_force = np.where(touching, np.maximum(elastic * (1.0 + damping_factor), 0.0), 0.0)
    # Friction: a spring to the sticking anchor plus slip damping, capped at friction * F_n.
    anchors[~touching] = np.nan
    new = touching & np.isnan(anchors[:, 0])
    anchors[new] = points[new]
    # The anchor rolls with the sphere: the stretch grows by the material point's slip only.
    anchors[touching & ~new] -= rolling[touching & ~new] * time_step
    stretch = points - anchors
    tangential_stretch = stretch - np.sum(stretch * normals, axis=1)[:, None] * normals
    slip = velocity - normal_speed[:, None] * normals
    trial = -config.tangential_stiffness * tangential_stretch - config.tangential_damping * slip
    trial_norm = np.linalg.norm(trial, axis=1)
    limit = config.friction * normal_force
    sliding = touching & (trial_norm > limit)
    friction = trial * np.where(sliding, limit / np.maximum(trial_norm, 1e-12), 1.0)[:, None]
    # A sliding foot drags its anchor along so that the spring alone carries the capped force.
    anchors[sliding] = points[sliding] + friction[sliding] / config.tangential_stiffness
    forces = np.where(touching[:, None], normal_force[:, None] * normals + friction, 0.0)
    local_points = np.einsum("lji,lj->li", feet.tibia_rotations, points - feet.tibia_origins)
    contacts = FootContacts(forces, normal_force, np.where(touching[:, None], normals, 0.0), points, touching)
    return contacts, local_points


class ContactArrays(NamedTuple):
    """Where `hard_finger_into` writes: FootContacts' arrays and the points in the tibias' frames."""
    forces: np.ndarray
    normal_forces: np.ndarray
    normals: np.ndarray
    points: np.ndarray
    local_points: np.ndarray


@njit(cache=True)
def hard_finger_into(feet, law, boxes, candidates, anchors, out):
    """`hard_finger` on the terrain's `boxes` (BOX records; each foot's `candidates` boxes), compiled:
    `feet` a WorldFeet, `law` a COMPLIANT record, `out` a ContactArrays (normals zero where a foot
    does not touch); updates `anchors` in place (rolled with the spheres over `law.time_step`).
    Returns the touching feet as bits (leg i: 1 << i)."""
    radius = law.radius
    depth, normals = sphere_contact_arrays(feet.centers, radius, boxes, candidates)
    centers, spins = feet.centers, feet.spins
    bits = 0
    for leg in range(len(centers)):
        normal = normals[leg]
        for i in range(3):
            out.points[leg, i] = centers[leg, i] - radius * normal[i]
            out.forces[leg, i] = 0.0
            out.normals[leg, i] = 0.0
        out.normal_forces[leg] = 0.0
        if not depth[leg] > 0.0:
            anchors[leg] = np.nan
            continue
        bits |= 1 << leg
        # Scalars rather than (3,) arrays: each array is a heap allocation in compiled code.
        arm = (out.points[leg, 0] - centers[leg, 0], out.points[leg, 1] - centers[leg, 1],
               out.points[leg, 2] - centers[leg, 2])
        rolling = (spins[leg, 1] * arm[2] - spins[leg, 2] * arm[1], spins[leg, 2] * arm[0] - spins[leg, 0] * arm[2],
                   spins[leg, 0] * arm[1] - spins[leg, 1] * arm[0])
        velocity = (feet.velocities[leg, 0] + rolling[0], feet.velocities[leg, 1] + rolling[1],
                    feet.velocities[leg, 2] + rolling[2])
        normal_speed = velocity[0] * normal[0] + velocity[1] * normal[1] + velocity[2] * normal[2]
        damping_factor = min(max(law.damping * -normal_speed, -1.0), 1.0)
        normal_force = max(law.stiffness * depth[leg] ** law.exponent * (1.0 + damping_factor), 0.0)
        out.normal_forces[leg] = normal_force
        if np.isnan(anchors[leg, 0]):
            anchors[leg] = out.points[leg]
        else:
            for i in range(3):
                anchors[leg, i] -= rolling[i] * law.time_step
        stretch = (out.points[leg, 0] - anchors[leg, 0], out.points[leg, 1] - anchors[leg, 1],
                   out.points[leg, 2] - anchors[leg, 2])
        along = stretch[0] * normal[0] + stretch[1] * normal[1] + stretch[2] * normal[2]
        trial = (-law.tangential_stiffness * (stretch[0] - along * normal[0])
                 - law.tangential_damping * (velocity[0] - normal_speed * normal[0]),
                 -law.tangential_stiffness * (stretch[1] - along * normal[1])
                 - law.tangential_damping * (velocity[1] - normal_speed * normal[1]),
                 -law.tangential_stiffness * (stretch[2] - along * normal[2])
                 - law.tangential_damping * (velocity[2] - normal_speed * normal[2]))
        trial_norm = math.sqrt(trial[0] ** 2 + trial[1] ** 2 + trial[2] ** 2)
        limit = law.friction * normal_force
        sliding = trial_norm > limit
        scale = limit / max(trial_norm, 1e-12) if sliding else 1.0
        for i in range(3):
            out.forces[leg, i] = normal_force * normal[i] + trial[i] * scale
            out.normals[leg, i] = normal[i]
            if sliding:
                anchors[leg, i] = out.points[leg, i] + trial[i] * scale / law.tangential_stiffness
    _points_in_tibias(feet, out.points, out.local_points)
    return bits


@njit(cache=True)
def _points_in_tibias(feet, points, local):
    """World `points` (6, 3) in each tibia's frame, R^T (p - o) leg by leg, into `local`."""
    rotations, origins = feet.tibia_rotations, feet.tibia_origins
    for leg in range(len(points)):
        for i in range(3):
            local[leg, i] = (rotations[leg, 0, i] * (points[leg, 0] - origins[leg, 0])
                             + rotations[leg, 1, i] * (points[leg, 1] - origins[leg, 1])
                             + rotations[leg, 2, i] * (points[leg, 2] - origins[leg, 2]))


# ---------------------------------------------------------------- the compliant model, per step
# The compliant model's parameters (the hard-finger law's) and what it keeps between steps: the
# sticking anchors, and the forces it applies to the tibias at the points in their frames.
COMPLIANT = np.dtype([("radius", np.float64), ("stiffness", np.float64), ("exponent", np.float64),
                      ("damping", np.float64), ("tangential_stiffness", np.float64),
                      ("tangential_damping", np.float64), ("friction", np.float64),
                      ("time_step", np.float64),                # s, the physics step the anchors roll over
                      ("anchors", np.float64, (LEGS, 3)), ("applied_forces", np.float64, (LEGS, 3)),
                      ("applied_offsets", np.float64, (LEGS, 3))])


def compliant_record(config: ContactConfig, foot_radius: float, time_step: float) -> np.ndarray:
    """A one-element COMPLIANT array with no anchor and no force yet, for a physics step of
    `time_step` s."""
    return one_record(COMPLIANT, radius=foot_radius, stiffness=config.stiffness, exponent=config.exponent,
                      damping=config.damping, tangential_stiffness=config.tangential_stiffness,
                      tangential_damping=config.tangential_damping, friction=config.friction,
                      time_step=time_step, anchors=np.nan,
                      applied_forces=0.0, applied_offsets=0.0)


def _contact_flags() -> tuple[np.ndarray, ...]:
    """The (6,) bool contact flags of each set of touching feet (bits), shared by the steps that
    have it: read-only."""
    flags = []
    for bits in range(1 << LEGS):
        flag = np.array([(bits >> leg) & 1 == 1 for leg in range(LEGS)])
        flag.flags.writeable = False
        flags.append(flag)
    return tuple(flags)


IN_CONTACT = _contact_flags()


class CompliantContact(ContactModel):
    """The hard-finger feet on the terrain as external forces: each step's forces follow from the
    state read out after the step before (an explicit step), and act during the next DART step."""

    name = "compliant"

    def __init__(self, config, terrain: Terrain):
        super().__init__(config, terrain)
        record = compliant_record(config.contact, config.robot.foot_radius, config.run.time_step)
        self._model = raw(record)                   # what the kernels read and update
        self.anchors = record["anchors"][0]         # views of it
        self._applied_forces, self._applied_offsets = record["applied_forces"][0], record["applied_offsets"][0]
        rule = terrain.candidate_rule()
        self._boxes, self._rule = raw(terrain.boxes.records), None if rule is None else raw(rule)
        self._body_corners = body_corners(config.robot.body_size)
        self._acting, self._pending, self._pending_bits = FootContacts.none(), FootContacts.none(), 0
        self._applications: tuple = ((),) * (1 << LEGS)

    def attach(self, simulation) -> None:
        # Per set of touching feet (bits), the addExtForce calls that apply the forces.
        self._applications = tuple(
            tuple((simulation.tibias[leg].addExtForce, self._applied_forces[leg], self._applied_offsets[leg])
                  for leg in range(LEGS) if bits >> leg & 1) for bits in range(1 << LEGS))

    def apply(self) -> None:
        """The forces computed from the latest state, on the tibias whose feet touch."""
        for add_force, force, offset in self._applications[self._pending_bits]:
            add_force(force, offset, False, True)
        self._acting = self._pending

    def read_state(self, positions, velocities, read_out_raw):
        """The state read-out with the next step's contact computed from it, in one compiled call
        (two for a terrain with candidate boxes of its own, found in Python between them)."""
        if self._rule is not None:
            state, finite, up, self._pending_bits = _read_out_and_hard_finger(
                positions, velocities, read_out_raw, self._model, self._boxes, self._rule)
            return state, finite, up
        state, finite, up = read_out(positions, velocities, read_out_raw)
        if finite:
            candidates = np.ascontiguousarray(self.terrain.candidates(state["foot_centers"]), dtype=np.int64)
            self._pending_bits = _hard_finger_among(state, self._model, self._boxes, candidates)
        return state, finite, up

    def update(self, state: np.ndarray) -> FootContacts:
        """The contacts that acted during the step just taken; the next step's are in `state`."""
        self._pending = FootContacts(state["contact_forces"], state["contact_normal_forces"], state["contact_normals"],
                                     state["contact_points"], IN_CONTACT[self._pending_bits])
        return self._acting

    def pending(self) -> FootContacts:
        """The contacts the next step applies."""
        return self._pending

    def body_touches_ground(self, state: np.ndarray) -> bool:
        """Whether a corner of the body's box lies inside the terrain."""
        if self._rule is None:
            corners = self._body_corners @ state["rotation"].T + state["position"]
            distance, _ = self.terrain.closest(corners)
            return bool((distance < 0.0).any())
        return _corners_in_ground(self._body_corners, state, self._boxes, self._rule)


def body_corners(body_size) -> np.ndarray:
    """(8, 3) corners of the body's box in the body frame."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    return signs * np.asarray(body_size, dtype=float) / 2


@njit(cache=True)
def _read_out_and_hard_finger(positions, velocities, read_out_raw, model_raw, boxes_raw, rule_raw):
    """state.read_out, then the compliant model's next step on the feet it read out, among the
    candidate boxes of the terrain's CANDIDATE_RULE (all records as bytes): the STATE array, whether
    it is finite, world_from_body[2, 2], and the touching feet as bits."""
    state = np.zeros((), STATE)
    finite, up = read_out_into(positions, velocities, the_record(read_out_raw.view(READ_OUT)), state[()])
    if not finite:
        return state, finite, up, 0
    candidates = candidates_by_rule(state[()].foot_centers, rule_raw.view(CANDIDATE_RULE))
    return state, finite, up, _hard_finger_step(state[()], model_raw, boxes_raw, candidates)


@njit(cache=True)
def _hard_finger_among(state, model_raw, boxes_raw, candidates):
    """The compliant model's next step on the feet of the 0-d STATE array `state` among given
    candidate boxes: the touching feet as bits."""
    return _hard_finger_step(state[()], model_raw, boxes_raw, candidates)


@njit(cache=True)
def _hard_finger_step(state, model_raw, boxes_raw, candidates):
    """hard_finger_into on the feet of the STATE record `state`, into its contact fields; the
    applied forces and offsets of the touching feet and the anchors into the COMPLIANT record."""
    model = the_record(model_raw.view(COMPLIANT))
    local_points = np.empty((LEGS, 3))
    feet = WorldFeet(state.foot_centers, state.foot_velocities, state.tibia_spins, state.tibia_rotations,
                     state.tibia_origins)
    out = ContactArrays(state.contact_forces, state.contact_normal_forces, state.contact_normals,
                        state.contact_points, local_points)
    bits = hard_finger_into(feet, model, boxes_raw.view(BOX), candidates, model.anchors, out)
    for leg in range(LEGS):
        if (bits >> leg) & 1:
            for i in range(3):
                model.applied_forces[leg, i] = state.contact_forces[leg, i]
                model.applied_offsets[leg, i] = local_points[leg, i]
    return bits


@njit(cache=True)
def _corners_in_ground(corners, state, boxes_raw, rule_raw):
    """Whether any of the body's `corners` (body frame), placed at the read-out `state`'s pose, lies
    inside a candidate box of the terrain (BOX records and CANDIDATE_RULE, as bytes)."""
    boxes = boxes_raw.view(BOX)
    pose = state[()]
    world = np.empty_like(corners)
    for row in range(len(corners)):
        for i in range(3):
            world[row, i] = (pose.rotation[i, 0] * corners[row, 0] + pose.rotation[i, 1] * corners[row, 1]
                             + pose.rotation[i, 2] * corners[row, 2]) + pose.position[i]
    candidates = candidates_by_rule(world, rule_raw.view(CANDIDATE_RULE))
    for row in range(len(world)):
        if closest_distance(world[row], boxes, candidates[row]) < 0.0:
            return True
    return False


# ---------------------------------------------------------------- DART's rigid contact
BODY = -1                   # what DartContact._collision_object_leg answers for the body's shapes


class DartContact(ContactModel):
    """DART's rigid contact: its collision detection and boxed LCP, on the terrain's boxes as a DART
    skeleton. The contacts are read back from DART's collision result, per foot."""

    name = "dart"
    dart_collisions = True

    def __init__(self, config, terrain: Terrain):
        super().__init__(config, terrain)
        self.friction = config.contact.friction
        self.cone_corrections = 0          # DART contact forces projected back onto the cone
        self.worst_cone_ratio = 1.0        # worst |F_t| / (mu F_n) that DART reported
        self._body_touches = False
        self._collision_legs: dict[object, int | None] = {}

    def attach(self, simulation) -> None:
        # DART's boxed LCP bounds each of two friction directions by mu * F_n: a pyramid whose
        # corners reach sqrt(2) * mu * F_n. Giving it mu / sqrt(2) inscribes the pyramid in the
        # true cone, so no contact force it returns leaves the friction cone.
        pyramid = self.friction / np.sqrt(2.0)
        simulation.add_terrain_to_world(pyramid)
        for tibia in simulation.tibias:
            for node in tibia.getShapeNodes():
                if node.hasDynamicsAspect():
                    node.getDynamicsAspect().setFrictionCoeff(pyramid)
                    node.getDynamicsAspect().setRestitutionCoeff(0.0)
        self.foot_shape_leg = {tibia.getShapeNodes()[-1].getName(): leg for leg, tibia in enumerate(simulation.tibias)}
        self._world = simulation.world

    def update(self, state: np.ndarray) -> FootContacts:
        # Sums in Python floats, contact by contact in DART's order: a dozen numpy calls per contact
        # would cost more than the sums.
        forces, normals, points = ([[0.0, 0.0, 0.0] for _ in range(LEGS)] for _ in range(3))
        counts = [0.0] * LEGS
        self._body_touches = False
        for contact in self._world.getLastCollisionResult().getContacts():
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

    def body_touches_ground(self, state: np.ndarray) -> bool:
        return self._body_touches

    def _collision_object_leg(self, collision_object) -> int | None:
        """The leg whose foot `collision_object` is, BODY for the body, None for anything else.
        Asking DART for a shape's name costs a binding call, so the answer is kept per collision
        object (dartpy hands back the same Python object for the same DART collision object)."""
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
        limit = self.friction * normal_forces
        over = touching & (magnitude > limit * (1 + 1e-9) + 1e-9)
        if not over.any():
            return forces
        self.cone_corrections += int(over.sum())
        ratio = float(np.max(magnitude[over] / np.maximum(limit[over], 1e-12)))
        self.worst_cone_ratio = max(self.worst_cone_ratio, ratio)
        scale = np.where(over, limit / np.maximum(magnitude, 1e-12), 1.0)
        return normal_forces[:, None] * normals + tangential * scale[:, None]
