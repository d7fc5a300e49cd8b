"""The paper's hard-finger contact (section 3.3), applied as external forces at each foot.

Normal force: a nonlinear spring-damper of the indentation d of the foot sphere in the terrain,
Hunt-Crossley form F_n = k d^n (1 + c d') (Hunt & Crossley 1975; n = 1.5 is Hertz's sphere on a
plane), never pulling. The damping vanishes with d, so the force is continuous at touch-down; the
damping factor c d' is bounded to [-1, 1] (at most twice the elastic force): a fast impact then
cannot produce an impulse that an explicit 1 ms step turns unstable on a light tibia.

Tangential force: Coulomb friction, proportional to F_n and opposite to the slip velocity while
sliding. It is regularised with a stick-slip spring (an elasto-plastic bristle, as in Dahl's and
LuGre's models) rather than by a viscous slope around zero slip: a viscous regularisation steep
enough to hold a robot on a slope for seconds is unstable at a 1 ms explicit step, while the
spring holds it exactly and only the force cap mu * F_n decides when the foot slides.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.world.config import ContactConfig
from testbed.world.terrain import Terrain, sphere_contact_arrays


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


class CompliantContact:
    """Hard-finger feet on a terrain; keeps the sticking anchors between steps."""

    def __init__(self, config: ContactConfig, terrain: Terrain, foot_radius: float):
        self.config = config
        self.terrain = terrain
        self.radius = foot_radius
        self.anchors = np.full((6, 3), np.nan)
        self.parameters = np.array([foot_radius, config.stiffness, config.exponent, config.damping,
                                     config.tangential_stiffness, config.tangential_damping, config.friction])
        # The base Terrain's candidates are every box, whatever the points: ask once, not every step.
        self._fixed_candidates = (terrain.candidates(np.zeros((6, 3)))
                                  if type(terrain).candidates is Terrain.candidates else None)

    def compute(self, centers: np.ndarray, links: np.ndarray) -> tuple[FootContacts, np.ndarray]:
        """Forces for foot spheres at `centers` (6, 3) whose links move as `links` (6, 6, 3): per foot
        the sphere centre's velocity, the link's angular velocity, the three rows of world_from_link
        and the link's origin, all world. Also the contact points in the links' frames, where the
        forces are applied. (The simulation runs the same model, `hard_finger_into`, inside its state
        read-out; tests/testbed/test_simulation_state.py holds the two equal bit for bit.)"""
        boxes = self.terrain.boxes
        candidates = self._fixed_candidates if self._fixed_candidates is not None else self.terrain.candidates(centers)
        forces, normal_forces, normals, points, touching, local_points = _hard_finger(
            centers, links, self.anchors, self.parameters, boxes.centers, boxes.half_extents, boxes.rotations,
            candidates)
        return FootContacts(forces, normal_forces, normals, points, touching), local_points

    def reset(self) -> None:
        self.anchors[:] = np.nan


# Compiled with numba: six feet of a dozen vector operations each, which numpy spent ~100 us per
# physics step on in call overhead. The loop is the model of the module docstring, foot by foot.
@njit(cache=True)
def _hard_finger(centers, links, anchors, parameters, box_centers, box_halves, box_rotations, candidates):
    """Forces, normal forces, contact normals, contact points and flags of the feet, and the contact
    points in the links' frames; updates the sticking `anchors` (NaN rows: no anchor) in place."""
    n = len(centers)
    forces, normal_force, normals, points, local_points = (np.empty((n, 3)), np.empty(n), np.empty((n, 3)),
                                                           np.empty((n, 3)), np.empty((n, 3)))
    bits = hard_finger_into(centers, links[:, 0], links[:, 1], links[:, 2:5], links[:, 5], anchors, parameters,
                            box_centers, box_halves, box_rotations, candidates, forces, normal_force, normals, points,
                            local_points)
    touching = np.empty(n, np.bool_)
    for leg in range(n):
        touching[leg] = (bits >> leg) & 1 == 1
    return forces, normal_force, normals, points, touching, local_points


@njit(cache=True)
def hard_finger_into(centers, center_velocities, spins, link_rotations, link_origins, anchors, parameters, box_centers,
                     box_halves, box_rotations, candidates, forces, normal_force, normals_out, points, local_points):
    """The model for feet at `centers` (n, 3) whose links move as kinematics.world_feet_arrays gives
    them (sphere centre velocities, link spins, world_from_link rotations and link origins), written
    into `forces`, `normal_force`, `normals_out` (zero rows where a foot does not touch), the contact
    `points` and those points in the links' frames (`local_points`); updates the sticking `anchors`
    (NaN rows: no anchor) in place. Returns the touching feet as bits (leg i: 1 << i). The output
    arrays may be views of one array (the state read-out's frame), but not of an input."""
    radius, stiffness, exponent, damping, tangential_stiffness, tangential_damping, friction = parameters
    depth, normals = sphere_contact_arrays(centers, radius, box_centers, box_halves, box_rotations, candidates)
    n = len(centers)
    velocity, slip, trial = np.empty(3), np.empty(3), np.empty(3)
    bits = 0
    for leg in range(n):
        normal, spin = normals[leg], spins[leg]
        for i in range(3):
            points[leg, i] = centers[leg, i] - radius * normal[i]
            forces[leg, i] = 0.0
            normals_out[leg, i] = 0.0
        normal_force[leg] = 0.0
        # Scalars rather than (3,) arrays: each array is a heap allocation in compiled code.
        arm = (points[leg, 0] - centers[leg, 0], points[leg, 1] - centers[leg, 1], points[leg, 2] - centers[leg, 2])
        velocity[0] = center_velocities[leg, 0] + spin[1] * arm[2] - spin[2] * arm[1]
        velocity[1] = center_velocities[leg, 1] + spin[2] * arm[0] - spin[0] * arm[2]
        velocity[2] = center_velocities[leg, 2] + spin[0] * arm[1] - spin[1] * arm[0]
        if not depth[leg] > 0.0:
            anchors[leg] = np.nan
            continue
        bits |= 1 << leg
        normal_speed = velocity[0] * normal[0] + velocity[1] * normal[1] + velocity[2] * normal[2]
        damping_factor = min(max(damping * -normal_speed, -1.0), 1.0)
        normal_force[leg] = max(stiffness * depth[leg] ** exponent * (1.0 + damping_factor), 0.0)
        # Friction: a spring to the sticking anchor plus slip damping, capped at friction * F_n.
        if np.isnan(anchors[leg, 0]):
            anchors[leg] = points[leg]
        stretch = (points[leg, 0] - anchors[leg, 0], points[leg, 1] - anchors[leg, 1], points[leg, 2] - anchors[leg, 2])
        along = stretch[0] * normal[0] + stretch[1] * normal[1] + stretch[2] * normal[2]
        for i in range(3):
            slip[i] = velocity[i] - normal_speed * normal[i]
            trial[i] = -tangential_stiffness * (stretch[i] - along * normal[i]) - tangential_damping * slip[i]
        trial_norm = math.sqrt(trial[0] ** 2 + trial[1] ** 2 + trial[2] ** 2)
        limit = friction * normal_force[leg]
        scale = limit / max(trial_norm, 1e-12) if trial_norm > limit else 1.0
        for i in range(3):
            forces[leg, i] = normal_force[leg] * normal[i] + trial[i] * scale
            normals_out[leg, i] = normal[i]
        if trial_norm > limit:
            # A sliding foot drags its anchor along so that the spring alone carries the capped force.
            for i in range(3):
                anchors[leg, i] = points[leg, i] + trial[i] * scale / tangential_stiffness
    points_in_links(link_rotations, link_origins, points, local_points)
    return bits


@njit(cache=True)
def points_in_links(rotations: np.ndarray, origins: np.ndarray, points: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(6, 3) world `points` in each link's frame, R^T (p - o) leg by leg, into `local`."""
    for leg in range(len(points)):
        for i in range(3):
            local[leg, i] = (rotations[leg, 0, i] * (points[leg, 0] - origins[leg, 0])
                             + rotations[leg, 1, i] * (points[leg, 1] - origins[leg, 1])
                             + rotations[leg, 2, i] * (points[leg, 2] - origins[leg, 2]))
    return local
