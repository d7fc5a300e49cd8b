"""Posture controller: keep the body level with respect to gravity and at a constant height above
the ground under it, by moving the feet's body-frame targets before inverse kinematics.

Inputs are the estimator's roll and pitch (with respect to gravity) and its body height above the
stance feet's plane; an estimator without a terrain plane (the attitude-only baselines) gets the
height from the joint encoders through forward kinematics instead. Never ground truth.

The correction is a pose of the body relative to the gait's frame: rotations about the body's x
and y axes and a vertical offset, each driven by a discrete PI loop (docs/control.md: plant,
design and margins). A foot target p in the gait frame becomes R^T (p - d) in the body frame,
with R = Ry(pitch correction) Rx(roll correction) and d = (0, 0, height correction): the feet stay
on the ground, so the body turns by R and rises by d.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from testbed.control.config import PostureConfig
from testbed.model.kinematics import LegGeometry, foot_positions, rows_times_matrix


class PostureMeasurement(NamedTuple):
    roll: float                 # rad, body with respect to gravity
    pitch: float                # rad
    height: float | None        # m, body origin above the stance feet's ground plane, vertically


class PiLoop:
    """u = -(kp e + ki * integral of e), discretised with a backward-Euler integrator (the same
    C(z) = kp + ki dt z / (z - 1) that docs/control.md analyses), clamped to +-limit.

    Anti-windup by conditional integration: the integral stops while the output is saturated in
    the direction the error pushes, and while the caller says the output cannot be realised."""

    def __init__(self, kp: float, ki: float, dt: float, limit: float):
        self.kp, self.ki, self.dt, self.limit = kp, ki, dt, limit
        self.integral = 0.0
        self.output = 0.0

    def update(self, error: float, hold: bool = False) -> float:
        self.integral, self.output = pi_step(self.integral, self.output, error, hold, self.kp, self.ki, self.dt,
                                             self.limit)
        return self.output

    @property
    def gains(self) -> tuple[float, float, float, float]:
        """(kp, ki, dt, limit): pi_step's constants for this loop."""
        return self.kp, self.ki, self.dt, self.limit


# Plain Python from PiLoop.update; compiled into the pilot's per-tick kernel (one source for both).
@register_jitable
def pi_step(integral: float, output: float, error: float, hold: bool, kp: float, ki: float, dt: float,
            limit: float) -> tuple[float, float]:
    """PiLoop.update on the loop's state: the new (integral, output)."""
    if not math.isfinite(error):
        return integral, output          # a missing or broken measurement: keep the last command
    updated = integral + error * dt
    raw = -(kp * error + ki * updated)
    saturated = abs(raw) > limit and math.copysign(1.0, raw) == math.copysign(1.0, -error)
    if not (hold or saturated):
        integral = updated
    else:
        raw = -(kp * error + ki * integral)
    return integral, min(max(raw, -limit), limit)


class PostureController:
    def __init__(self, config: PostureConfig, dt: float, height_reference: float):
        limit = math.radians(config.max_tilt_correction_deg)
        self.roll = PiLoop(config.tilt_kp, config.tilt_ki, dt, limit)
        self.pitch = PiLoop(config.tilt_kp, config.tilt_ki, dt, limit)
        self.height = PiLoop(config.height_kp, config.height_ki, dt, config.max_height_correction)
        self.height_reference = height_reference

    def update(self, measurement: PostureMeasurement | None, hold: bool = False) -> None:
        """One control tick. `hold` (the last targets were out of reach) freezes the integrators."""
        if measurement is None:
            return
        self.roll.update(measurement.roll, hold)
        self.pitch.update(measurement.pitch, hold)
        if measurement.height is not None:
            self.height.update(measurement.height - self.height_reference, hold)

    @property
    def correction(self) -> tuple[float, float, float]:
        """(roll rad, pitch rad, height m) of the body relative to the gait frame."""
        return self.roll.output, self.pitch.output, self.height.output

    def apply(self, feet: np.ndarray) -> np.ndarray:
        """Gait-frame foot targets (6, 3) -> body-frame targets."""
        return tilted_targets(feet, self.roll.output, self.pitch.output, self.height.output)

    def to_gait_frame(self, feet: np.ndarray) -> np.ndarray:
        """Body-frame positions (6, 3) -> gait frame: the inverse of `apply`."""
        return untilted_positions(feet, self.roll.output, self.pitch.output, self.height.output, np.empty_like(feet))


# Compiled, with the products in numpy's order (rows_times_matrix): each transform was a handful
# of numpy calls and a 3x3 matrix built from a list, 5.9 us a tick for the two, against 1.9 us.
@njit(cache=True)
def correction_rotation(roll: float, pitch: float) -> np.ndarray:
    """Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rotation = np.empty((3, 3))
    rotation[0, 0], rotation[0, 1], rotation[0, 2] = cp, sp * sr, sp * cr
    rotation[1, 0], rotation[1, 1], rotation[1, 2] = 0.0, cr, -sr
    rotation[2, 0], rotation[2, 1], rotation[2, 2] = -sp, cp * sr, cp * cr
    return rotation


@njit(cache=True)
def tilted_targets(feet: np.ndarray, roll: float, pitch: float, height: float) -> np.ndarray:
    """Foot targets (n, 3) for a body turned by R = Ry(pitch) Rx(roll) and raised by
    d = (0, 0, height) over them: rows R^T (p - d), numpy's `(p - d) @ R` bit for bit."""
    shifted = feet.copy()
    shifted[:, 2] -= height
    return rows_times_matrix(shifted, correction_rotation(roll, pitch), np.empty_like(shifted))


@njit(cache=True)
def untilted_positions(feet, roll, pitch, height, out):
    """The inverse of tilted_targets, written into `out` (another array than `feet`): rows
    R p + d, numpy's `p @ R.T + d`."""
    rows_times_matrix(feet, correction_rotation(roll, pitch).T, out)
    out[:, 2] += height
    return out


def kinematic_height(geometry: LegGeometry, joints: np.ndarray, stance: np.ndarray, roll: float,
                     pitch: float, foot_radius: float) -> float | None:
    """Body origin above the plane of the stance feet's ground points, vertically, from the joint
    encoders and the attitude: the feet rotated into a level frame, a least-squares plane through
    them, evaluated under the body origin. None with fewer than three stance feet."""
    if stance.sum() < 3:
        return None
    level = foot_positions(geometry, joints)[stance] @ correction_rotation(roll, pitch).T
    design = np.column_stack([np.ones(len(level)), level[:, :2]])
    (offset, slope_x, slope_y), *_ = np.linalg.lstsq(design, level[:, 2], rcond=None)
    # The sphere centres lie foot_radius above the ground along its normal.
    return float(-offset + foot_radius * math.sqrt(1.0 + slope_x ** 2 + slope_y ** 2))


def estimated_height(body_height: float, terrain_roll: float, terrain_pitch: float) -> float:
    """The estimator's distance to the support plane (along its normal) as a vertical height."""
    return body_height / (math.cos(terrain_roll) * math.cos(terrain_pitch))
