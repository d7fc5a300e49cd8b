"""Planted feet that roll: the stance paths of spheres that turn with their tibias.

A foot is a sphere of radius r on the tibia's end. As the body passes over a planted foot its tibia
turns, and a sphere that does not slip rolls: its centre moves by dphi x (r n) over ground of normal
n, dphi the tibia's turn. On a corner leg the tibia tilts in the leg's plane as the foot moves along
the leg, about 2.5 mm of rolling per tripod stance at 0.1 m/s; the middle legs hardly roll. Stance
paths that moved every planted centre as one rigid body would make the rigid contact's feet slip by
that much, at the friction limit (docs/control.md, "Stance paths that roll").

The law is `testbed.model.kinematics.sphere_rolling_shift`, the fusion filters' too: from the joint
increments, th2 + th3 tilt the tibia in its leg's vertical plane, th1 turns it about z_b, which
rolls nothing on level ground (on a slope, where the ground's normal is not z_b, it does). Here it
is applied to the encoders' joint angles, sample by sample, with n the normal of the planted feet's
plane: the turn the tibia made. Rolled by the commanded joints' turn instead, the rigid contact's
feet were squeezed inwards by 2.6-5.4 N from their landing to their lift-off (docs/control.md).
"""

from __future__ import annotations

import math

import numpy as np

from testbed.control.gait import walk_plane
from testbed.model.kinematics import LegGeometry, sphere_rolling_shift

STILL_BODY = np.zeros(3)


def sphere_rolling(joints: np.ndarray, previous: np.ndarray, geometry: LegGeometry, radius: float,
                   normal: np.ndarray) -> np.ndarray:
    """(6, 3) m, how far each foot's sphere centre moves, rolling without slip on ground of unit
    `normal` (body frame), as its leg's joints go from `previous` to `joints` (18,) rad."""
    return sphere_rolling_shift(np.asarray(joints, dtype=float), np.asarray(previous, dtype=float),
                                geometry.base_angle, STILL_BODY, normal, radius)


def ground_normal(feet: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """The unit normal of the least-squares plane of the `planted` rows of `feet` (6, 3; body
    frame), z_b with fewer than three."""
    _, slope_x, slope_y = walk_plane(feet, planted, 0.0)
    normal = np.array([-slope_x, -slope_y, 1.0])
    return normal / math.sqrt(normal.dot(normal))


class StanceRolling:
    """Moves each planted foot's target, encoder sample by encoder sample, by its sphere's
    rolling since touch-down.

    A foot counts from the second sample it is planted at, so the landing itself rolls nothing.
    The body's tilt against the gait frame (the posture correction, a few degrees) turns each
    shift by that angle, which is neglected."""

    def __init__(self, geometry: LegGeometry, radius: float, joints: np.ndarray):
        self.geometry = geometry
        self.radius = radius
        self.previous = np.array(joints, dtype=float)
        self.planted_before = np.zeros(6, dtype=bool)

    def roll(self, feet: np.ndarray, joints: np.ndarray, planted: np.ndarray, joint_feet: np.ndarray) -> None:
        """Move the rows of `feet` (6, 3; gait frame, in place) planted now and at the last call by
        their spheres' rolling from the last call's `joints` (18,) rad to these, on the plane of the
        `planted` rows of `joint_feet` (6, 3; body frame, the feet at `joints`)."""
        both = planted & self.planted_before
        if both.any():
            normal = ground_normal(joint_feet, planted)
            shift = sphere_rolling(joints, self.previous, self.geometry, self.radius, normal)
            np.add(feet, shift, out=feet, where=both[:, None])
        self.previous[:] = joints
        self.planted_before[:] = planted
