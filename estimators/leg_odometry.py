"""Stance-foot kinematics for the fusion filters: which feet are down, and where they are.

Foot positions come from the encoder angles through the paper's eq. 2 (forward kinematics).
A foot counts as planted while its contact flag is set and it carries at least `min_force`: a
lightly loaded foot is touching down or lifting off and still moving (in the DART runs feet under
5 N move at 4 to 18 cm/s, loaded ones creep at under 1 cm/s). A foot's filter state is valid from
the first encoder sample after it was planted until it is not.
"""

from __future__ import annotations

import numpy as np

from testbed.kinematics import LegGeometry, foot_positions

NUM_LEGS = 6


class StanceTracker:
    def __init__(self, geometry: LegGeometry, min_force: float = 0.0):
        self.geometry = geometry
        self.min_force = min_force
        self.contact = np.zeros(NUM_LEGS, dtype=bool)     # planted feet, from the latest foot sample
        self.tracked = np.zeros(NUM_LEGS, dtype=bool)     # feet whose filter state is valid

    def add_contacts(self, contact: np.ndarray, normal_forces: np.ndarray) -> None:
        with np.errstate(invalid="ignore"):
            loaded = np.asarray(normal_forces, dtype=float) >= self.min_force    # NaN (dropped): not loaded
        self.contact = np.asarray(contact, dtype=bool) & loaded
        self.tracked &= self.contact

    def feet(self, positions: np.ndarray) -> np.ndarray:
        """(6, 3) foot centres in the body frame, from O_b; NaN rows for legs with a bad reading."""
        positions = np.asarray(positions, dtype=float).reshape(NUM_LEGS, 3)
        feet = foot_positions(self.geometry, positions)
        feet[~np.isfinite(positions).all(axis=1)] = np.nan
        return feet

    def measurable(self, feet: np.ndarray) -> np.ndarray:
        """(6,) bool: down now and read by the encoders."""
        return self.contact & np.isfinite(feet).all(axis=1)
