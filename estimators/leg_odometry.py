"""Stance-foot kinematics for the fusion filters: which feet are down, and where they are.

Foot positions come from the encoder angles through the paper's eq. 2 (forward kinematics).
The filters track each foot's sphere centre. A planted sphere rolls, it does not stay put: as the
tibia turns in the world by dphi, the centre moves by dphi x (r n) (rolling without slip on ground
of normal n). With a 1 cm foot that is 2 mm for the body's 12 deg calibration tilt, seven times a
foot's kinematic noise; `StanceTracker.read` applies it (the tibia's turn is the body's, from the
filter, plus the joints', from the encoders).
A foot counts as planted while its contact flag is set and it carries at least `min_force`: a
lightly loaded foot is touching down or lifting off and still moving (in the DART runs feet under
5 N move at 4 to 18 cm/s, loaded ones creep at under 1 cm/s). A foot's filter state is valid from
the first encoder sample after it was planted until it is not.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.model.kinematics import LegGeometry, sphere_rolling_shift, world_feet_of

NUM_LEGS = 6
_IDENTITY, _ORIGIN = np.eye(3), np.zeros(3)
_STILL = (_IDENTITY, _ORIGIN, _ORIGIN, _ORIGIN)    # a body at the origin, at rest
_NO_RATES = np.zeros(3 * NUM_LEGS)


class Reading(NamedTuple):
    """One encoder sample seen by the tracker. The arrays are the tracker's own, rewritten by its
    next reading."""
    feet: np.ndarray          # (6, 3) foot centres in the body frame, from O_b; NaN rows for bad readings
    measured: np.ndarray      # (6, 3) the same from the tracker's `origin`
    measurable: np.ndarray    # (6,) bool: down now and read by the encoders
    tracked: np.ndarray       # legs measurable with a valid filter state
    new: np.ndarray           # legs measurable without one (planted since the last reading)


# A tracker's geometry, state and reading buffers, fields by name (`StanceTracker.record`).
STANCE_TRACKER = np.dtype([
    ("base_angle", "f8", NUM_LEGS), ("base_distance", "f8", NUM_LEGS),     # rad, m: the legs' bases
    ("femur", "f8"), ("tibia", "f8"),                                       # m
    ("origin", "f8", 3),                  # m, body frame: where `measured` is taken from
    ("contact", "u1", NUM_LEGS),          # planted feet, from the latest foot sample
    ("tracked", "u1", NUM_LEGS),          # feet whose filter state is valid
    ("previous", "f8", 3 * NUM_LEGS),     # rad, the joint angles of the previous rolling reading
    ("have_previous", "u1"),
    ("feet", "f8", (NUM_LEGS, 3)), ("measured", "f8", (NUM_LEGS, 3)), ("measurable", "u1", NUM_LEGS),
    ("legs", "i8", NUM_LEGS),             # tracked legs, then new ones
], align=True)     # (flags as u1: numba's records hold no boolean arrays; Python sees them as bool)


class StanceTracker:
    def __init__(self, geometry: LegGeometry, min_force: float = 0.0, origin: np.ndarray | None = None):
        self.geometry = geometry
        self.min_force = min_force
        self.record = np.zeros(1, dtype=STANCE_TRACKER)
        fields = self.record[0]
        fields["base_angle"], fields["base_distance"] = geometry.base_angle, geometry.base_distance
        fields["femur"], fields["tibia"] = geometry.femur, geometry.tibia
        self.origin = fields["origin"]
        if origin is not None:
            self.origin[:] = origin
        self.contact = fields["contact"].view(np.bool_)
        self.tracked = fields["tracked"].view(np.bool_)
        self._buffers = fields["feet"], fields["measured"], fields["measurable"].view(np.bool_), fields["legs"]

    def add_contacts(self, contact: np.ndarray, normal_forces: np.ndarray) -> None:
        contact, normal_forces = np.asarray(contact, dtype=bool), np.asarray(normal_forces, dtype=float)
        if contact.shape != (NUM_LEGS,) or normal_forces.shape != (NUM_LEGS,):
            raise ValueError(f"a foot sample needs {NUM_LEGS} contacts and forces, got {contact.shape}, "
                             f"{normal_forces.shape}")
        _add_contacts(contact, normal_forces, self.min_force, self.contact, self.tracked)

    def feet(self, positions: np.ndarray) -> np.ndarray:
        """(6, 3) foot centres in the body frame, from O_b; NaN rows for legs with a bad reading."""
        # eq. 2 through the testbed's compiled kinematics (a body at the origin, at rest: its world
        # frame is the body frame); a NaN joint angle gives its leg a NaN foot.
        g = self.geometry
        return world_feet_of(*_STILL, np.asarray(positions, dtype=float), _NO_RATES, g.arrays[0])[0]

    def read(self, positions: np.ndarray, rolling: tuple[np.ndarray, np.ndarray, tuple, float] | None) -> Reading:
        """`feet`, `measured` and `measurable` of an encoder sample, with the measurable legs split into tracked
        and new ones. With `rolling` = (filter_feet, body_turn, up, foot_radius), the tracked rows of
        the filter's foot states `filter_feet` (body frame) first move, in place, by how far their
        spheres rolled since the previous reading: each tibia's turn (`body_turn`, the body's
        rotation vector since then, plus the joints') crossed with r n, n = `up` in the body frame;
        not at all for a leg without two valid readings."""
        positions = np.asarray(positions, dtype=float).reshape(3 * NUM_LEGS)
        filter_feet, body_turn, up, radius = _NO_ROLLING if rolling is None else rolling
        tracked_count, new_count = _read(positions, self.record, rolling is not None, filter_feet, body_turn, up,
                                         radius)
        feet, measured, measurable, legs = self._buffers
        return Reading(feet, measured, measurable, legs[:tracked_count], legs[tracked_count:tracked_count + new_count])


_NO_ROLLING = (np.zeros((NUM_LEGS, 3)), np.zeros(3), (0.0, 0.0, 0.0), 0.0)


# Compiled: the fusion filters read every encoder sample through it; as separate kernel and
# numpy calls (feet, rolling shift, masks, index lists) the per-call cost would dominate.
@njit(cache=True)
def _read(positions, record, rolling, filter_feet, body_turn, up, radius):
    """The reading of the joint angles `positions` into the STANCE_TRACKER record's buffers; with
    `rolling`, the tracked feet of `filter_feet` roll first (StanceTracker.read). Returns the
    numbers of tracked and new legs."""
    t = record[0]
    if rolling:
        if t.have_previous:
            shift = sphere_rolling_shift(positions, t.previous, t.base_angle, body_turn, up, radius)
            for leg in range(NUM_LEGS):
                if t.tracked[leg]:
                    filter_feet[leg] += shift[leg]
        t.previous[:] = positions
        t.have_previous = True
    feet = world_feet_of(_IDENTITY, _ORIGIN, _ORIGIN, _ORIGIN, positions, _NO_RATES, t)[0]
    t.feet[:] = feet
    t.measured[:] = feet - t.origin
    tracked_count = 0
    for leg in range(NUM_LEGS):
        t.measurable[leg] = t.contact[leg] and np.isfinite(feet[leg, 0]) and np.isfinite(feet[leg, 1]) \
            and np.isfinite(feet[leg, 2])
        if t.measurable[leg] and t.tracked[leg]:
            t.legs[tracked_count] = leg
            tracked_count += 1
    new_count = 0
    for leg in range(NUM_LEGS):
        if t.measurable[leg] and not t.tracked[leg]:
            t.legs[tracked_count + new_count] = leg
            new_count += 1
    return tracked_count, new_count


# Compiled: it runs at every foot sample (250 Hz).
@njit(cache=True)
def _add_contacts(contact, normal_forces, min_force, planted, tracked):
    """planted = contact and loaded (a NaN force, dropped, is not), in place; tracked &= planted."""
    for leg in range(NUM_LEGS):
        planted[leg] = contact[leg] and normal_forces[leg] >= min_force
        tracked[leg] = tracked[leg] and planted[leg]


