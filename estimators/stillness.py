"""Still windows: spans in which the body neither turns nor shakes, so that the mean specific force
is gravity (plus the accelerometer's offset) with the sensor's noise alone.

The fusion filters otherwise see gravity only through the legs: a tilt error makes the strapdown
velocity drift, and the feet notice within a few steps. That is weak over short spans (a 1 mg
error moves a foot 0.05 mm in 0.1 s, a sixth of its kinematic noise), which is what a still body
can do better: its mean specific force over 50 ms measures the gravity direction to ~1 mg. Here,
with the start-up calibration poses (testbed/startup.py), that is what tells the accelerometer's
offset from a tilt. The test is the zero-velocity detector of pedestrian and legged navigation
(Skog et al. 2010, "Zero-velocity detection: an algorithm evaluation"): the angular rate and the
specific force stay within thresholds for the whole window. Windows do not overlap, so no sample
is used twice. A still window also gives the gyro's mean reading, which for a body known to stand
(the start-up) is its bias: the zero angular rate update of the same literature.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


class StillMean(NamedTuple):
    """A completed still window's means."""
    force: np.ndarray       # (3,) m/s^2, specific force
    rate: np.ndarray        # (3,) rad/s, the gyro's reading (bias included)


class StillWindow:
    def __init__(self, duration: float, max_rate: float, max_force_change: float):
        self.duration = duration                    # s
        self.max_rate = max_rate                    # rad/s, per interval, after the gyro bias
        self.max_force_change = max_force_change    # m/s^2, an interval's mean force from the window's first
        self._time = 0.0
        self._force_sum = (0.0, 0.0, 0.0)
        self._turn_sum = (0.0, 0.0, 0.0)
        self._first: tuple[float, float, float] | None = None

    def add(self, dt: float, turn, force, bias) -> StillMean | None:
        """An interval of `dt` s with the gyro's rotation vector `turn` after the filter's bias
        `bias` (rad/s) and the mean specific force `force` (3-sequences). Returns the window's means
        when a still window completes."""
        # On Python floats: the filters call this at every step, and numpy's per-call cost on
        # three elements would be most of its cost.
        x, y, z = turn
        still = math.sqrt(x * x + y * y + z * z) <= self.max_rate * dt
        fx, fy, fz = force
        if still and self._first is not None:
            first, limit = self._first, self.max_force_change
            still = abs(fx - first[0]) <= limit and abs(fy - first[1]) <= limit and abs(fz - first[2]) <= limit
        if not still:
            if self._first is not None:     # else the window is empty already
                self.reset()
            return None
        if self._first is None:
            self._first = (fx, fy, fz)
        sx, sy, sz = self._force_sum
        self._force_sum = (sx + fx * dt, sy + fy * dt, sz + fz * dt)
        bx, by, bz = bias
        rx, ry, rz = self._turn_sum
        self._turn_sum = (rx + x + bx * dt, ry + y + by * dt, rz + z + bz * dt)
        self._time += dt
        if self._time < self.duration - 1e-9:     # sums of dt round
            return None
        mean = StillMean(np.array(self._force_sum) / self._time, np.array(self._turn_sum) / self._time)
        self.reset()
        return mean

    def reset(self) -> None:
        self._time = 0.0
        self._force_sum = (0.0, 0.0, 0.0)
        self._turn_sum = (0.0, 0.0, 0.0)
        self._first = None
