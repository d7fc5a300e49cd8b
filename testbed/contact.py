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

from dataclasses import dataclass

import numpy as np

from testbed.config import ContactConfig
from testbed.terrain import Terrain


@dataclass(frozen=True)
class FootContacts:
    """Contact result for the six feet, world frame."""
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

    def compute(self, centers: np.ndarray, center_velocities: np.ndarray, angular_velocities: np.ndarray) -> FootContacts:
        """Forces for foot spheres at `centers` moving with `center_velocities`, links turning at
        `angular_velocities` (all (6, 3), world)."""
        cfg = self.config
        depth, normals = self.terrain.sphere_contacts(centers, self.radius)
        touching = depth > 0.0
        points = centers - self.radius * normals
        velocities = center_velocities + np.cross(angular_velocities, points - centers)
        normal_speed = np.einsum("ij,ij->i", velocities, normals)
        damping = np.clip(cfg.damping * -normal_speed, -1.0, 1.0)
        normal_force = cfg.stiffness * depth**cfg.exponent * (1.0 + damping)
        normal_force = np.where(touching, np.maximum(normal_force, 0.0), 0.0)
        tangential = self._friction(points, velocities - normal_speed[:, None] * normals, normals,
                                    normal_force, touching)
        forces = normal_force[:, None] * normals + tangential
        normals = np.where(touching[:, None], normals, 0.0)
        return FootContacts(forces, normal_force, normals, points, touching)

    def _friction(self, points, slip_velocities, normals, normal_force, touching) -> np.ndarray:
        cfg = self.config
        new = touching & np.isnan(self.anchors[:, 0])
        self.anchors[new] = points[new]
        self.anchors[~touching] = np.nan
        stretch = np.where(touching[:, None], points - self.anchors, 0.0)
        stretch -= np.einsum("ij,ij->i", stretch, normals)[:, None] * normals
        trial = -cfg.tangential_stiffness * stretch - cfg.tangential_damping * slip_velocities
        trial_norm = np.linalg.norm(trial, axis=1)
        limit = cfg.friction * normal_force
        sliding = touching & (trial_norm > limit)
        scale = np.where(sliding, limit / np.maximum(trial_norm, 1e-12), 1.0)
        force = np.where(touching[:, None], trial * scale[:, None], 0.0)
        # A sliding foot drags its anchor along so that the spring alone carries the capped force.
        self.anchors[sliding] = points[sliding] + force[sliding] / cfg.tangential_stiffness
        return force

    def reset(self) -> None:
        self.anchors[:] = np.nan
