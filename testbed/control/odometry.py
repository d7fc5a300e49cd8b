"""The robot's own planar pose, for walking straight and to targets without ground truth.

Leg odometry: feet in stance stay where they are on the ground, so between two encoder samples
the body moved by the rigid planar motion that carries the stance feet's new body-frame positions
onto their old ones (the least-squares alignment of the two point sets).
Heading: feet twist on the ground a little at every step, which leg odometry cannot see, so the
heading comes from the gyro, whose bias is calibrated while the robot stands still at start-up.
The leg displacements are rotated into the world with that heading, and with the gyro's turn
between two samples one stance foot is enough to fix the body's shift.

Which point of a foot stays put: the encoders give the centre of the foot sphere. A sphere that
sticks to the ground rolls when its tibia pitches, and then its centre moves by the foot radius
times the pitch change, on both simulated contacts (docs/estimators.md, "Position drift on DART
contact"). The odometry does not model the rolling; it weighs each foot by how far its centre may
have rolled since it was planted: feet whose tibia keeps its pitch (the middle legs walking
straight) fix the body's motion.

Gaps: between two samples that share no stance foot the legs measure nothing (the tripods change
over, one lifting before the other carries weight, or a landing foot bounces), yet the body moves
on, about 5 % of the distance at 0.1 m/s. With no foot on the ground the body's horizontal
velocity does not change, so the odometry carries it on at the velocity the legs measured last.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.model import spatial as rot
from testbed.model.kinematics import LegGeometry, foot_positions_arrays

# m: one foot's position error from the encoders (0.9 mrad per joint of noise and quantization
# through about 0.23 m of leg). It sets the scale below which a foot's rolling does not matter.
FOOT_POSITION_STD = 2e-4
VELOCITY_WINDOW = 10    # encoder samples (50 ms at 200 Hz) averaged into the velocity that bridges a gap


class _Reading(NamedTuple):
    table: np.ndarray           # (6, 3) per foot: centre x, y (body frame), trust in it staying put
    stance: np.ndarray          # (6,) bool
    heading: float | None

    @property
    def feet(self) -> np.ndarray:
        return self.table[:, :2]

    @property
    def weights(self) -> np.ndarray:
        return self.table[:, 2]


NO_FEET = np.zeros(6, bool)


class LegOdometry:
    def __init__(self, geometry: LegGeometry, foot_radius: float = 0.0):
        self.geometry = geometry
        self.foot_radius = foot_radius
        self.x = 0.0
        self.y = 0.0
        self.yaw = 0.0
        self._reference: _Reading | None = None
        self._samples = 0                       # encoder samples since the reference (dropouts count)
        self._planted_pitch = np.zeros(6)       # tibia pitch th2 + th3 of each foot when it was planted
        self._recent: deque[tuple[float, float]] = deque(maxlen=VELOCITY_WINDOW)   # body-frame shifts per sample

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.x, self.y, self.yaw

    def update(self, joint_positions: np.ndarray, stance: np.ndarray, heading: float | None = None) -> None:
        """A new encoder reading (18,) rad with the legs known to be on the ground (6,) bool; with
        `heading` (rad, from the gyro) the displacement is rotated by it instead of the legs' yaw."""
        self._samples += 1
        reading = self._read(np.asarray(joint_positions, dtype=float), np.array(stance, dtype=bool), heading)
        if reading is None:
            return   # an encoder dropout: keep the last good reading as the reference
        if self._reference is not None:
            self._advance(self._reference, reading, self._samples)
        self._reference, self._samples = reading, 0

    def _read(self, joint_positions: np.ndarray, stance: np.ndarray, heading: float | None) -> _Reading | None:
        # Feet put down since the last reading (at the first reading, every stance foot) take
        # this reading's tibia pitch as their planted pitch.
        before = self._reference.stance if self._reference is not None else NO_FEET
        finite, table = _reading_table(joint_positions, stance, before, self._planted_pitch, self.foot_radius,
                                       FOOT_POSITION_STD**2, self.geometry.arrays)
        return _Reading(table, stance, heading) if finite else None

    def _advance(self, before: _Reading, after: _Reading, samples: int) -> None:
        motion = _rigid_motion(before, after)
        if motion is None:
            # No foot measured this stretch: the body carries on at its recent velocity.
            velocity = np.mean(self._recent, axis=0) if self._recent else np.zeros(2)
            turn, (shift_x, shift_y) = 0.0, (velocity * samples).tolist()
        else:
            turn, shift_x, shift_y = motion
            self._recent.append((shift_x / samples, shift_y / samples))
        self._move(shift_x, shift_y, before.heading)
        self.yaw = self.yaw + turn if after.heading is None else after.heading

    def _move(self, shift_x: float, shift_y: float, heading: float | None) -> None:
        """Add a shift given in the body frame of the reference reading: rotated by its heading
        (by the legs' yaw without one)."""
        yaw = self.yaw if heading is None else heading
        c, s = math.cos(yaw), math.sin(yaw)
        self.x += c * shift_x - s * shift_y
        self.y += s * shift_x + c * shift_y


def _rigid_motion(before: _Reading, after: _Reading) -> tuple[float, float, float] | None:
    """The body's planar motion (turn, shift x and y in the earlier body frame) between two readings
    of the ground-fixed feet in stance at both, before = R(turn) @ after + shift in the weighted
    least-squares sense. The turn is the gyro's when both headings are known (one foot suffices),
    otherwise the planar Kabsch solution (two feet needed). None when the feet cannot fix the
    motion. Weights come from both readings: a weight taken from one reading alone shares that
    reading's encoder noise with the foot positions, and the product drifts a standing robot's pose."""
    if before.heading is not None and after.heading is not None:
        turn = float(rot.wrap_angle(after.heading - before.heading))
        planted, shift_x, shift_y = _shift_for_turn(before.table, after.table, before.stance, after.stance, turn)
        return (turn, shift_x, shift_y) if planted else None
    both = before.stance & after.stance
    if both.sum() < 2:
        return None
    turn, shift = _kabsch_motion(before.feet[both], after.feet[both], (before.weights + after.weights)[both])
    return turn, *shift.tolist()


def _kabsch_motion(before: np.ndarray, after: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray]:
    """The planar Kabsch angle: atan2 of the weighted sums of the cross and dot products of the
    centred points. (scipy's 3-D align_vectors leaves the rotation about the axis of two feet
    undetermined, so the planar problem is solved here directly.) And the shift for it."""
    w = weights / weights.sum()
    centre_before, centre_after = w @ before, w @ after
    b, a = before - centre_before, after - centre_after
    turn = float(np.arctan2(w @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), w @ np.sum(a * b, axis=1)))
    c, s = np.cos(turn), np.sin(turn)
    shift = centre_before - np.array([c * centre_after[0] - s * centre_after[1], s * centre_after[0] + c * centre_after[1]])
    return turn, shift


# The per-sample arithmetic of the gyro path is compiled: it runs at every encoder sample.
@njit(cache=True)
def _reading_table(q, stance, stance_before, planted_pitch, foot_radius, variance, legs):
    """(whether the reading is finite, its table): per foot its centre x, y (eq. 2, geometry from
    the LEG_ARRAYS record `legs`) and the trust in it staying put, 1 / (variance + rolled^2),
    rolled being the foot radius times the tibia's pitch change since the foot was planted. Feet
    in `stance` but not in `stance_before` are planted now: `planted_pitch` takes their pitch."""
    table = np.empty((6, 3))
    for angle in q:
        if not math.isfinite(angle):
            return False, table
    for leg in range(6):
        if stance[leg] and not stance_before[leg]:
            planted_pitch[leg] = q[3 * leg + 1] + q[3 * leg + 2]
    feet = foot_positions_arrays(q, legs)
    for leg in range(6):
        rolled = foot_radius * (q[3 * leg + 1] + q[3 * leg + 2] - planted_pitch[leg])
        table[leg, 0], table[leg, 1] = feet[leg, 0], feet[leg, 1]
        table[leg, 2] = 1.0 / (variance + rolled * rolled)
    return True, table


@njit(cache=True)
def _shift_for_turn(before, after, stance_before, stance_after, turn):
    """(whether a foot stood in both readings, shift x, shift y): the shift that carries those
    feet of reading `after`, turned by `turn`, onto those of `before` in the weighted
    least-squares sense (tables of _reading_table)."""
    count = 0
    for leg in range(6):
        count += stance_before[leg] and stance_after[leg]
    if count == 0:
        return False, 0.0, 0.0
    total = 0.0
    centre_before, centre_after = np.zeros(2), np.zeros(2)
    for leg in range(6):
        if stance_before[leg] and stance_after[leg]:
            weight = before[leg, 2] + after[leg, 2]
            total += weight
            for axis in range(2):
                centre_before[axis] += weight * before[leg, axis]
                centre_after[axis] += weight * after[leg, axis]
    centre_before /= total
    centre_after /= total
    c, s = math.cos(turn), math.sin(turn)
    return (True, centre_before[0] - (c * centre_after[0] - s * centre_after[1]),
            centre_before[1] - (s * centre_after[0] + c * centre_after[1]))


class GyroHeading:
    """Yaw from the gyro, its bias averaged over a still start-up period.

    The whole rotation is integrated, and the heading read from it: while the body is tilted (the
    start-up's calibration poses, slopes), the body z rate is not the yaw rate, and summing it
    alone turned the heading by 1.4 deg over the poses."""

    def __init__(self, calibration_time: float, body_from_sensor: np.ndarray | None = None):
        self.calibration_time = calibration_time
        # the gyro's mounting: its rates turn into the body frame (identity: they are body rates)
        self.body_from_sensor = np.eye(3) if body_from_sensor is None else np.array(body_from_sensor, dtype=float)
        self.yaw = 0.0
        self.bias = np.zeros(3)
        self.bias_variance = math.inf       # (rad/s)^2, of the bias's z component
        self._sum = np.zeros(3)
        self._square_z = 0.0
        self._count = 0
        self._attitude = np.array(rot.IDENTITY)      # world_from_body since the start, (x, y, z, w)
        self._last_t: float | None = None

    def update(self, t: float, gyro: np.ndarray) -> None:
        """A gyro sample (3,) rad/s at time t, in the sensor frame; one that is not finite is ignored."""
        if t >= self.calibration_time and self._last_t is not None:
            finite, yaw = _turn(self._attitude, self.body_from_sensor, gyro, self.bias, t - self._last_t)
            if not finite:
                return
            self.yaw = yaw
        else:
            rate = rot.matvec3(self.body_from_sensor, gyro)
            if not np.isfinite(rate).all():
                return
            if t < self.calibration_time:
                self._sum += rate
                self._square_z += rate[2] ** 2
                self._count += 1
                self.bias = self._sum / self._count
                if self._count > 1:      # the variance of the mean, from the samples' spread
                    spread = (self._square_z - self._count * self.bias[2] ** 2) / (self._count - 1)
                    self.bias_variance = max(spread, 0.0) / self._count
        self._last_t = t

    def adopt_bias(self, t: float, bias_z: float, variance: float) -> None:
        """Another estimate at time t of the gyro's z bias (rad/s, body frame; an estimator's,
        which can observe it through the legs while walking), taken in place of the start-up
        average when it is known better: heading errors grow with the bias error times the time
        walked. The heading integrated so far with the old bias is corrected by the difference
        times the time since the start-up average (a constant bias; about the vertical, which
        the body's z axis is while it walks level)."""
        if not (math.isfinite(bias_z) and math.isfinite(variance) and 0.0 <= variance < self.bias_variance
                and self._count > 0 and t >= self.calibration_time):
            return
        turn = -(bias_z - self.bias[2]) * (t - self.calibration_time)
        self._attitude = np.array(rot.multiply(rot.exp(0.0, 0.0, turn), tuple(self._attitude)))
        self.yaw = rot.yaw_of(tuple(self._attitude))
        self.bias[2] = bias_z
        self.bias_variance = variance


# Compiled: it runs at the IMU rate.
@njit(cache=True)
def _turn(attitude, body_from_sensor, gyro, bias, dt):
    """(whether the rate is finite, the new yaw): `attitude` (x, y, z, w) followed, in place, by the
    body-frame rotation (body_from_sensor gyro - bias) dt, through testbed.model.spatial's helpers
    (tests/testbed/test_odometry_and_stability.py compares them)."""
    rate = rot.matvec3(body_from_sensor, gyro)
    for axis in range(3):
        if not math.isfinite(rate[axis]):
            return False, 0.0
    rx, ry, rz = (rate[0] - bias[0]) * dt, (rate[1] - bias[1]) * dt, (rate[2] - bias[2]) * dt
    turned = rot.rotate_by_vector((attitude[0], attitude[1], attitude[2], attitude[3]), rx, ry, rz)
    attitude[0], attitude[1], attitude[2], attitude[3] = turned
    return True, rot.yaw_of(turned)
