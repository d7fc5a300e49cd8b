"""Posture control: keep the body level with respect to gravity and at a constant height above
the ground under it, by moving the feet's body-frame targets before inverse kinematics.

A posture law turns what the robot measures (the estimator's roll and pitch with respect to
gravity, and its body height above the stance feet's plane; an estimator without a terrain plane
gets the height from the joint encoders through forward kinematics) into a correction: a pose of
the body relative to the gait's frame, rotations about the body's x and y axes and a vertical
offset. Never ground truth. The built-in law (`pi`) is a discrete PI loop per axis
(docs/control.md: plant, design and margins); another law plugs in through `posture.law`.

A foot target p in the gait frame becomes R^T (p - d) in the body frame, with
R = Ry(pitch correction) Rx(roll correction) and d = (0, 0, height correction): the feet stay on
the ground, so the body turns by R and rises by d.
"""

from __future__ import annotations

import abc
import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from estimators.base import Estimate
from testbed.model.errors import PluginFailure
from testbed.model.kinematics import LegGeometry, foot_positions, rows_times_matrix
from testbed.model.registry import Registry


class PostureMeasurement(NamedTuple):
    """What a posture law is given each tick: errors from the level body at the stance height."""
    roll: float                     # rad, body with respect to gravity (the estimate's)
    pitch: float                    # rad
    height_error: float | None      # m, body height above the stance feet's plane less the commanded height
                                    # (robot.stance_height less the pilot's crouch); None when not measurable
                                    # (fewer than three stance feet)


class PostureCorrection(NamedTuple):
    """The body's pose relative to the gait frame that a posture law commands."""
    roll: float = 0.0               # rad, about the body's x axis
    pitch: float = 0.0              # rad, about its y axis
    height: float = 0.0             # m, up


class PostureLaw(abc.ABC):
    """A posture law, built-in or a user's plugin (`posture.law = "MODULE:CLASS"`).

    A class method `from_config(config)` receives the run's `Config` when present; otherwise the
    class is built with no arguments. The pilot calls `update` once per control tick
    (`run.time_step`) from the end of the start-up on (`Config.startup_time`), whenever the
    estimator has given an estimate; before that, and between updates, the last correction holds
    (zero at first). The pilot keeps the gait, its terrain adaptation and the inverse kinematics."""

    @abc.abstractmethod
    def update(self, t: float, measurement: PostureMeasurement, estimate: Estimate,
               limited: bool) -> PostureCorrection | tuple[float, float, float]:
        """The correction (roll rad, pitch rad, height m) for time t (s). `measurement`: the
        errors to remove; `estimate`: the estimator's latest estimate, for laws that want more
        of it (rates, covariances); `limited`: the last targets were out of reach of some leg,
        which kept its last joint angles (a law with integrators stops them, anti-windup)."""


POSTURE_LAWS = Registry.of_subclasses("posture law", "posture_laws", PostureLaw)


def checked_correction(value: Any, spec: str) -> PostureCorrection:
    """A law's answer as a PostureCorrection of three finite floats; anything else is a PluginFailure."""
    try:
        roll, pitch, height = value
        correction = PostureCorrection(float(roll), float(pitch), float(height))
    except (TypeError, ValueError):
        raise PluginFailure(f"posture law '{spec}' returned {value!r}, expected (roll, pitch, height)") from None
    if not (math.isfinite(correction.roll) and math.isfinite(correction.pitch) and math.isfinite(correction.height)):
        raise PluginFailure(f"posture law '{spec}' returned a non-finite correction {tuple(correction)}")
    return correction


class PiLoop:
    """u = -(kp e + ki * integral of e), discretised with a backward-Euler integrator (the same
    C(z) = kp + ki dt z / (z - 1) that docs/control.md analyses), clamped to +-limit.

    The part of the error beyond `large_error` has the proportional gain `large_kp` instead of
    `kp` (when `large_kp` is given): a foot sliding off an edge's corner tips the body by degrees
    within 50-100 ms, and the legs catch it the sooner the harder the loop answers; errors within
    `large_error` (the walk's own) see the linear loop of the design.

    Anti-windup by conditional integration: the integral stops while the output is saturated in
    the direction the error pushes, and while the caller says the output cannot be realised.
    A missing or broken (non-finite) error keeps the last output."""

    def __init__(self, kp: float, ki: float, dt: float, limit: float, large_error: float = math.inf,
                 large_kp: float | None = None):
        self.kp, self.ki, self.dt, self.limit = kp, ki, dt, limit
        self.large_error = large_error
        self.large_kp = kp if large_kp is None else large_kp
        self.integral = 0.0
        self.output = 0.0

    def proportional(self, error: float) -> float:
        """kp e, with `large_kp` for the part of e beyond `large_error`."""
        beyond = max(abs(error) - self.large_error, 0.0)
        return self.kp * error + (self.large_kp - self.kp) * math.copysign(beyond, error)

    def update(self, error: float, hold: bool = False) -> float:
        if not math.isfinite(error):
            return self.output
        ki, limit = self.ki, self.limit
        proportional = self.proportional(error)
        updated = self.integral + error * self.dt
        raw = -(proportional + ki * updated)
        saturated = abs(raw) > limit and math.copysign(1.0, raw) == math.copysign(1.0, -error)
        if hold or saturated:
            raw = -(proportional + ki * self.integral)
        else:
            self.integral = updated
        self.output = min(max(raw, -limit), limit)
        return self.output


class PiPostureLaw(PostureLaw):
    """The built-in law (`pi`): a PI loop on roll, one on pitch, one on height (`[posture]` gains).
    The tilt loops answer the part of an error beyond `tilt_large_error` (rad) with `tilt_large_kp`
    (`PiLoop`); within it, where the walk's own errors stay, they are the linear design of
    docs/control.md."""

    @classmethod
    def from_config(cls, config) -> "PiPostureLaw":
        posture = config.posture
        return cls(posture.tilt_kp, posture.tilt_ki, posture.height_kp, posture.height_ki,
                   math.radians(posture.max_tilt_correction_deg), posture.max_height_correction, config.run.time_step,
                   tilt_large_error=math.radians(posture.tilt_large_error_deg), tilt_large_kp=posture.tilt_large_kp)

    def __init__(self, tilt_kp: float, tilt_ki: float, height_kp: float, height_ki: float, max_tilt: float,
                 max_height: float, dt: float, *, tilt_large_error: float = math.inf, tilt_large_kp: float | None = None):
        large = {"large_error": tilt_large_error, "large_kp": tilt_large_kp}
        self.roll = PiLoop(tilt_kp, tilt_ki, dt, max_tilt, **large)
        self.pitch = PiLoop(tilt_kp, tilt_ki, dt, max_tilt, **large)
        self.height = PiLoop(height_kp, height_ki, dt, max_height)

    def update(self, t: float, measurement: PostureMeasurement, estimate: Estimate | None,
               limited: bool) -> PostureCorrection:
        roll = self.roll.update(measurement.roll, limited)
        pitch = self.pitch.update(measurement.pitch, limited)
        error = measurement.height_error
        height = self.height.output if error is None else self.height.update(error, limited)
        return PostureCorrection(roll, pitch, height)


@njit(cache=True)
def correction_rotation(roll: float, pitch: float) -> np.ndarray:
    """R = Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rotation = np.empty((3, 3))
    rotation[0, 0], rotation[0, 1], rotation[0, 2] = cp, sp * sr, sp * cr
    rotation[1, 0], rotation[1, 1], rotation[1, 2] = 0.0, cr, -sr
    rotation[2, 0], rotation[2, 1], rotation[2, 2] = -sp, cp * sr, cp * cr
    return rotation


@njit(cache=True)
def gait_frame_tilt(roll: float, pitch: float, correction_roll: float, correction_pitch: float) -> tuple[float, float]:
    """(roll, pitch) of the gait frame with respect to gravity, for the body's attitude (roll,
    pitch) and the correction (the body's pose in the gait frame): R = R(body) R(correction)^T,
    read from its last row (the vertical in the gait frame)."""
    body, correction = correction_rotation(roll, pitch), correction_rotation(correction_roll, correction_pitch)
    up = np.zeros(3)
    for column in range(3):
        for k in range(3):
            up[column] += body[2, k] * correction[column, k]
    return math.atan2(up[1], up[2]), math.asin(min(1.0, max(-1.0, -up[0])))


@njit(cache=True)
def levelling_rotation(roll: float, pitch: float, correction_roll: float, correction_pitch: float,
                       share: float) -> np.ndarray:
    """The turn of the gait frame's contents that takes out `share` of the frame's tilt."""
    frame_roll, frame_pitch = gait_frame_tilt(roll, pitch, correction_roll, correction_pitch)
    return correction_rotation(share * frame_roll, share * frame_pitch)


def body_frame_targets(feet: np.ndarray, correction: PostureCorrection) -> np.ndarray:
    """Gait-frame foot targets (n, 3) -> body-frame targets: rows R^T (p - d)."""
    return (feet - [0.0, 0.0, correction.height]) @ correction_rotation(correction.roll, correction.pitch)


def gait_frame_positions(feet: np.ndarray, correction: PostureCorrection) -> np.ndarray:
    """Body-frame positions (n, 3) -> gait frame: rows R p + d, the inverse of body_frame_targets."""
    return feet @ correction_rotation(correction.roll, correction.pitch).T + [0.0, 0.0, correction.height]


# body_frame_targets and gait_frame_positions compiled, for the pilot's per-tick kernel
# (tests/testbed/test_posture.py compares them).
@njit(cache=True)
def tilted_targets(feet: np.ndarray, roll: float, pitch: float, height: float) -> np.ndarray:
    """body_frame_targets for the correction (roll, pitch, height): a new array."""
    shifted = feet.copy()
    shifted[:, 2] -= height
    return rows_times_matrix(shifted, correction_rotation(roll, pitch), np.empty_like(shifted))


@njit(cache=True)
def untilted_positions(feet, roll, pitch, height, out):
    """gait_frame_positions for the correction (roll, pitch, height), written into `out`
    (another array than `feet`)."""
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
