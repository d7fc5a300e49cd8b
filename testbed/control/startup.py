"""The start-up routine: stand still, then tilt the body through calibration poses, feet planted.

An accelerometer offset reads exactly like a tilt while the body only translates; the two separate
once the body turns about horizontal axes (gravity then moves through the sensor's axes, the
offset does not). So before walking the robot tilts its body to roll +tilt, roll -tilt,
pitch +tilt, pitch -tilt and back to level, holding each pose briefly, with its feet planted. The
estimators see only the sensors (the poses are in the joint encoders and the gyro); the fusion
filters estimate the offset over these seconds (estimators/fusion.py). Symmetric poses also
cancel, to first order, a gyro scale error in the rotation between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

# (roll, pitch) in units of the tilt, visited in this order after the still start.
POSES = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (0.0, 0.0))

# `gait.level_hold_time = "auto"` (s): a share of the run up to REFERENCE_RUN, so that a short run
# keeps its walk; beyond it the hold grows with the square of the run. The heading error a z gyro
# bias error leaves grows with the time walked, and the bias's reading error falls with the square
# root of the time held (docs/estimators.md, "The level hold"): a hold growing with the run's
# square keeps the heading error at the end of a long walk that of a REFERENCE_RUN walk.
AUTO_LEVEL_HOLD_SHARE = 0.05
REFERENCE_RUN = 40.0
AUTO_LEVEL_HOLD_RANGE = (0.2, 20.0)


def level_hold(setting: float | str, duration: float) -> float:
    """s the robot stands level after the poses: `gait.level_hold_time`, or with "auto" a share of
    the run's duration (s), which grows with the square of the duration beyond REFERENCE_RUN."""
    if setting != "auto":
        return float(setting)
    shortest, longest = AUTO_LEVEL_HOLD_RANGE
    hold = AUTO_LEVEL_HOLD_SHARE * duration * max(1.0, duration / REFERENCE_RUN)
    return min(max(hold, shortest), longest)


def minimum_jerk(fraction: float) -> float:
    """0 -> 1 with zero velocity and acceleration at both ends (Flash and Hogan 1985)."""
    s = min(max(fraction, 0.0), 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


@dataclass(frozen=True)
class CalibrationPoses:
    still: float        # s standing still first
    tilt: float         # rad
    rate: float         # rad/s, mean turn rate of a move from one pose to the next
    hold: float         # s at each tilted pose
    level_hold: float   # s level after the poses, before the walk

    @classmethod
    def from_gait(cls, gait, duration: float) -> "CalibrationPoses":
        """The poses of a `[gait]` config in a run of `duration` (s)."""
        return cls(gait.still_time, math.radians(gait.calibration_tilt_deg), math.radians(gait.calibration_rate_dps),
                   gait.calibration_hold_time, level_hold(gait.level_hold_time, duration))

    @cached_property
    def _moves(self) -> list[tuple[float, float, tuple[float, float], tuple[float, float]]]:
        """(start time, duration, from, to) of each move, from and to as (roll, pitch) in rad."""
        moves, t, previous = [], self.still, np.zeros(2)
        for pose in POSES:
            target = self.tilt * np.array(pose)
            duration = float(np.linalg.norm(target - previous)) / self.rate
            moves.append((t, duration, tuple(previous.tolist()), tuple(target.tolist())))
            t += duration + self.hold
            previous = target
        return moves

    @property
    def poses(self) -> list[tuple[float, float]]:
        """(roll, pitch) of each pose, rad: the body's tilt is largest there."""
        return [(self.tilt * roll, self.tilt * pitch) for roll, pitch in POSES]

    @property
    def end(self) -> float:
        """s from the start until the poses are over and the robot stands level again."""
        if self.tilt == 0.0:
            return self.still
        start, duration, _, _ = self._moves[-1]
        return start + duration + self.level_hold

    def rise(self, t: float) -> float:
        """Share (0 to 1) at time t of the body's rise to its stance height: over the first move of
        the poses (over the still time without poses), minimum jerk."""
        if self.tilt == 0.0:
            return minimum_jerk(min(1.0, t / self.still))
        start, duration, _, _ = self._moves[0]
        return minimum_jerk(min(1.0, max(0.0, (t - start) / duration)))

    def body_tilt(self, t: float) -> tuple[float, float]:
        """Commanded body (roll, pitch), rad, at time t."""
        if self.tilt == 0.0 or t <= self.still or t >= self.end:
            return 0.0, 0.0
        for start, duration, (roll_before, pitch_before), (roll_after, pitch_after) in reversed(self._moves):
            if t >= start:
                progress = minimum_jerk((t - start) / duration)
                return (roll_before + progress * (roll_after - roll_before),
                        pitch_before + progress * (pitch_after - pitch_before))
        return 0.0, 0.0
