"""IMU + leg-kinematics fusion: the models shared by `ekf` and `ukf`, and their common front end.

Nominal state: attitude q (world_from_body, yaw included), gyro bias b_g, accelerometer bias b_a,
the accelerometer z axis's cross-axis terms c (its reading per unit body x and y specific force),
the IMU point's velocity v and the six foot positions p_i relative to the IMU point, all in the
body frame (robocentric: the measurements never see yaw or position), the IMU point's position r
in the world (the frame of the start pose: origin at the body origin, x along the start heading,
z up). Error state (35): dx = [dtheta (local rotation vector), db_g, dv, db_a, dc, dp_1 ... dp_6,
dr] (Sola 2017, "Quaternion kinematics for the error-state Kalman filter", sections 5 and 6; foot
states as in Bloesch et al. 2012, "State Estimation for Legged Robots - Consistent Fusion of Leg
Kinematics and IMU", kept in the body frame). Position and yaw are unobservable: no measurement
reads them; the feet correct them only through their correlations with the velocity, the tilt
and the gyro bias, and their variances grow with the distance walked and the time.

Rolling feet: a planted foot sphere whose contact sticks rolls as its tibia turns, its centre moving
by s_i = dphi x (r n), n the ground's normal: the filter takes its terrain plane's
(`ground_normal_in_body`; testbed.model.kinematics.sphere_rolling_shift). Both simulated
contacts roll it: the pilot's stance paths move each planted centre by its own sphere's rolling (testbed/control/rolling.py), and
the compliant contact's friction spring stretches with the slip of the sphere's material contact
point, so a sphere that rolls feels no spring (testbed/world/contact.py). Measured from truth on
flat 30 s tripod walks (seeds 0-2), the front corner feet move 0.97-1.05 of the modelled rolling
per stance on both contacts, the rear ones 0.80-0.90 (docs/estimators.md, "Position drift on DART
contact"). The filter moves each tracked foot by k s_i with the rolling fraction
k = ROLLING_FRACTION = 1, and adds (ROLLING_STD s_i)^2 per axis to the foot's variance. It does not
know which contact model runs. (k as a state does not work: the encoder noise enters both the
rolling, through the joint increments, and the kinematics, which biases an estimated k down.)

The IMU drives the prediction (strapdown: the specific force is an input, not a measurement),
summed between filter steps by `preintegration` (Forster et al. 2017). Over an interval dt from
step i to step j, with u = R^T e_z the up direction in the body frame:
    R_j  = R_i dR
    v_j  = dR^T (v_i - g u_i dt + dv)
    p_j  = dR^T (p_i - v_i dt + g u_i dt^2 / 2 - dp)     a stance foot is fixed in the world
    r_j  = r_i + R_i (v_i dt + dp) - g e_z dt^2 / 2       (world frame)
    b_g, b_a                                             random walks
Measurement, at every encoder sample (200 Hz):
    stance foot i    FK_i(encoders) - r_imu = p_i         (forward kinematics, eq. 2 of the paper)
A foot's state restarts from its kinematics at every touchdown. A tilt error dtheta makes the
predicted velocity drift at g [u]x dtheta, which the stance feet see within a few steps: the leg
kinematics are what separate gravity from walking accelerations (the accelerometer reads both).
A constant accelerometer offset looks exactly like a tilt; the two separate only as the body turns
about a horizontal axis: b_a is estimated during the start-up calibration poses (testbed/startup.py:
the body tilts +-12 deg in roll and pitch on planted feet; still windows, estimators/stillness.py,
measure gravity g u + b_a + g (c . u_xy) e_z), then held as a "consider" state (Schmidt-Kalman):
no update moves it, its covariance widens the tilt's. Through small tilts the z axis's cross-axis
terms c read exactly as an offset plus a tilt (both change the z reading by g u_y, g u_x), so they
are states with their prior (the accelerometer's misalignment), held with b_a: not learnable
from the poses, but without them the filter takes them for an offset and reports that offset,
and the tilt it sets, as better known than they are. While no foot is tracked (encoder dropout),
the mean specific force of each step corrects the tilt as a gravity-direction measurement, its
noise the body acceleration.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from testbed.model import spatial as rot
from estimators.accel_array import AccelArrayFit, RateTracker
from estimators.base import ESTIMATE_ROWS, Estimate, EstimateRows, Estimates, Estimator, stacked_readings
from estimators.config import FusionConfig, TerrainEstimatorConfig
from estimators.gating import chi2_quantile
from estimators.leg_odometry import StanceTracker
from estimators.stillness import StillWindow
from estimators.preintegration import ACCEPTED, REJECTED, Preintegration, imu_sample
from estimators.terrain import TerrainFilter, grown_covariance
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from testbed.model.errors import ConfigError
from testbed.model.kinematics import LegGeometry

NUM_FEET = 6
FOOT0 = 14                     # error-state index of the first foot
POSITION0 = FOOT0 + 3 * NUM_FEET    # error-state index of the world position
ERROR_DIM = POSITION0 + 3
THETA, BIAS, VEL, ACCEL_BIAS = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
ACCEL_CROSS = slice(12, 14)    # the accelerometer z axis's sensitivity to the x and y specific force
ACCEL_ERRORS = slice(9, 14)    # offset and cross-axis terms: the consider block after the start-up
FEET = slice(FOOT0, POSITION0)
POSITION = slice(POSITION0, POSITION0 + 3)
# The rolling fraction k: both contacts roll the planted spheres (the pilot's stance paths roll
# them, the compliant contact's friction spring follows the material point), so k = 1; its spread:
# the rear corner feet move 0.80-0.90 of the modelled rolling per stance, the front ones 0.97-1.05
# (flat 30 s tripod walks, seeds 0-2, both contacts, from truth).
ROLLING_FRACTION, ROLLING_STD = 1.0, 0.2
# The velocity's scale error per unit error of k: on those walks the final error along the walk
# moves by 2.5 % (compliant) and 2.8 % (DART) of the distance from k = 0 to k = 1. With k known to
# ROLLING_STD, the velocity carries a scale error e of std ROLLING_STD * ROLLING_SHARE, the same over
# the walk, so the position's error is e times the displacement since the start. The filter's white
# noises cannot grow that way; the position is a leaf of the error state (no measurement reads it,
# nothing depends on it), so the term e's covariance adds to the reported position covariance alone.
ROLLING_SHARE = 0.027
INITIAL_POSITION_STD = 1e-3    # m: the start pose defines the frame; the body settles on its feet by a millimetre

VELOCITY_RANDOM_WALK = 1e-3    # m/s/sqrt(s): unmodelled accelerometer errors (scale, cross-axis, vibration)
MAX_STEP = 0.01                # s: without encoder samples, the filter steps on its own this often
# A gyro that repeats its reading exactly this many times in a row is stuck: its white noise (about
# 5 LSB per sample) makes that improbable beyond 1e-12 otherwise. A stuck gyro's rate is taken as
# zero, a missing reading is held (a short gap), and the attitude's variance grows by
# (BODY_RATE_STD * time without gyro)^2 per step: the body's unknown rate, which the feet correct.
STUCK_GYRO_SAMPLES = 5
BODY_RATE_STD = 1.0            # rad/s
ZERO = np.zeros(3)
MISSING = np.full(3, np.nan)   # a reading that is missing
I3 = np.eye(3)
ZERO33 = np.zeros((3, 3))
FLOAT64 = np.dtype(np.float64)


def foot(leg: int) -> slice:
    """The error-state slice of foot `leg`."""
    return slice(FOOT0 + 3 * leg, FOOT0 + 3 + 3 * leg)


# The arrays of a nominal state, fields by name: the EKF's state lives in one such record, which
# its compiled feet update injects into (`FusionEstimator.nominal`).
NOMINAL = np.dtype([("bias", "f8", 3), ("velocity", "f8", 3), ("accel_bias", "f8", 3), ("accel_cross", "f8", 2),
                    ("feet", "f8", (NUM_FEET, 3)), ("position", "f8", 3)])

# The bias step detector's sums (`BiasStepDetector.sums`).
TILT_SUMS = np.dtype([("correction", "f8", 3), ("covariance", "f8", (3, 3))])


@dataclass
class NominalState:
    q: rot.Quaternion
    bias: np.ndarray          # (3,) rad/s, gyro
    velocity: np.ndarray      # (3,) m/s, IMU point, body frame
    accel_bias: np.ndarray    # (3,) m/s^2
    feet: np.ndarray          # (6, 3) m, from the IMU point, body frame
    accel_cross: np.ndarray = field(default_factory=lambda: np.zeros(2))    # (2,) rad, z axis per x, y force
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))       # (3,) m, IMU point, world frame


def apply_preintegration(state: NominalState, pre: Preintegration, gravity: float) -> tuple[NominalState, np.ndarray]:
    """The nominal state after the preintegrated interval; also returns dR (3x3)."""
    dt = pre.dt
    up = np.array(rot.up_in_body(state.q))
    turn = rot.to_matrix(tuple(pre.dq))
    velocity = (state.velocity - gravity * dt * up + pre.dv) @ turn
    feet = (state.feet - (state.velocity * dt - 0.5 * gravity * dt * dt * up + pre.dp)) @ turn
    position = state.position + rot.to_matrix(state.q) @ (state.velocity * dt + pre.dp)
    position[2] -= 0.5 * gravity * dt * dt
    q = rot.normalized(rot.multiply(state.q, tuple(pre.dq)))
    return NominalState(q, state.bias, velocity, state.accel_bias, feet, state.accel_cross, position), turn


@dataclass(frozen=True)
class FusionNoise:
    """The FusionConfig numbers turned into variances."""
    gyro: float                 # rad^2/s
    bias_walk: float            # rad^2/s^3
    accel_density: float        # (m/s^2)^2 / Hz
    body_accel: float           # (m/s^2)^2
    accel_bias_walk: float      # (m/s^2)^2 / s
    foot_position: float        # m^2
    foot_slip: float            # m^2 / s

    @classmethod
    def from_config(cls, params: FusionConfig) -> "FusionNoise":
        return cls(params.gyro_noise_density**2, params.gyro_bias_random_walk**2, params.accel_noise_density**2,
                   params.body_accel_std**2, params.accel_bias_random_walk**2, params.foot_position_std**2,
                   params.foot_slip_std**2)

    def process(self, dt: float) -> np.ndarray:
        """Diagonal of the discrete process noise over dt (white noises integrated over dt)."""
        velocity = (self.accel_density + VELOCITY_RANDOM_WALK**2) * dt
        rates = np.zeros(ERROR_DIM)
        rates[:12] = np.repeat([self.gyro * dt, self.bias_walk * dt, velocity, self.accel_bias_walk * dt], 3)
        rates[FEET] = self.foot_slip * dt       # the cross-axis terms are constants; the position follows v
        return rates


def initial_covariance(params: FusionConfig, q: rot.Quaternion) -> np.ndarray:
    """Tilt uncertainty across the vertical, yaw uncertainty about it (both in body axes)."""
    up = np.array(rot.up_in_body(q))
    vertical = np.outer(up, up)
    tilt, yaw = math.radians(params.initial_tilt_std_deg), math.radians(params.initial_yaw_std_deg)
    covariance = np.zeros((ERROR_DIM, ERROR_DIM))
    covariance[THETA, THETA] = tilt**2 * (np.eye(3) - vertical) + yaw**2 * vertical
    covariance[BIAS, BIAS] = params.gyro_bias_initial_std**2 * np.eye(3)
    covariance[VEL, VEL] = params.initial_velocity_std**2 * np.eye(3)
    covariance[ACCEL_BIAS, ACCEL_BIAS] = params.accel_bias_initial_std**2 * np.eye(3)
    covariance[ACCEL_CROSS, ACCEL_CROSS] = params.accel_cross_axis_std**2 * np.eye(2)
    covariance[FEET, FEET] = params.foot_position_std**2 * np.eye(3 * NUM_FEET)    # restarted at touchdown
    covariance[POSITION, POSITION] = INITIAL_POSITION_STD**2 * np.eye(3)
    return covariance


def reset_jacobian(dtheta: np.ndarray) -> np.ndarray:
    """G of the error reset after injecting dtheta into q (Sola 2017, section 6.3)."""
    jacobian = np.eye(ERROR_DIM)
    jacobian[THETA, THETA] -= 0.5 * rot.skew(dtheta)
    return jacobian


@register_jitable
def foot_nis(P: np.ndarray, b: int, variance: float, y: np.ndarray) -> float:
    """A foot's normalised innovation squared y^T S^-1 y, S = P[b:b+3, b:b+3] + variance I (its
    state's block, from error-state index b), through the Cholesky factor of S in closed form (S is
    symmetric positive definite)."""
    l00 = math.sqrt(P[b, b] + variance)
    l10 = P[b + 1, b] / l00
    l20 = P[b + 2, b] / l00
    l11 = math.sqrt(P[b + 1, b + 1] + variance - l10 * l10)
    l21 = (P[b + 2, b + 1] - l20 * l10) / l11
    l22 = math.sqrt(P[b + 2, b + 2] + variance - l20 * l20 - l21 * l21)
    z0 = y[0] / l00
    z1 = (y[1] - l10 * z0) / l11
    z2 = (y[2] - l20 * z0 - l21 * z1) / l22
    return z0 * z0 + z1 * z1 + z2 * z2


def inject_in_place(state: NominalState, nominal: np.ndarray, dx: np.ndarray) -> None:
    """inject, modifying `state`, whose arrays are views of the NOMINAL record `nominal` (the EKF's path)."""
    state.q = inject_arrays(state.q, dx, nominal[0])


# Compiled: the EKF's feet update calls it from its kernel.
@njit(cache=True)
def inject_arrays(q: rot.Quaternion, dx: np.ndarray, x) -> rot.Quaternion:
    """inject into the nominal state's arrays, the NOMINAL record element x, in place; returns the
    new attitude."""
    x.bias[:] += dx[BIAS]
    x.velocity[:] += dx[VEL]
    x.accel_bias[:] += dx[ACCEL_BIAS]
    x.accel_cross[:] += dx[ACCEL_CROSS]
    x.feet[:] += dx[FEET].reshape(NUM_FEET, 3)
    x.position[:] += dx[POSITION]
    return rot.rotate_by_vector(q, dx[0], dx[1], dx[2])


def inject(state: NominalState, dx: np.ndarray) -> NominalState:
    """x_true = x (+) dx (Sola 2017, section 6.2)."""
    return NominalState(rot.rotate_by_vector(state.q, dx[0], dx[1], dx[2]), state.bias + dx[BIAS],
                        state.velocity + dx[VEL], state.accel_bias + dx[ACCEL_BIAS],
                        state.feet + dx[FEET].reshape(NUM_FEET, 3), state.accel_cross + dx[ACCEL_CROSS],
                        state.position + dx[POSITION])


@register_jitable
def horizontal_basis(up: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane perpendicular to `up`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = rot.matvec3(rot.skew(up), helper)
    first /= np.linalg.norm(first)
    basis = np.empty((2, 3))
    basis[0] = first
    basis[1] = rot.matvec3(rot.skew(up), first)
    return basis


# Compiled: one call instead of a dozen numpy ones on 2x2 and 3x3 arrays.
@njit(cache=True)
def drift_statistic(sums: np.ndarray, q: rot.Quaternion, extra_variance: float = 0.0) -> tuple[float, float]:
    """(chi-square statistic, norm) of the horizontal part of the summed tilt corrections in the
    TILT_SUMS record `sums`, at attitude q: d^T C^-1 d with d = B sum, C = B (sum K S K^T) B^T + v I,
    B the horizontal basis, v `extra_variance` (rad^2, per axis); the statistic is 0 when C is
    singular."""
    s = sums[0]
    basis = horizontal_basis(np.array(rot.up_in_body(q)))
    drift = basis @ s.correction
    covariance = basis @ s.covariance @ basis.T + extra_variance * np.eye(2)
    determinant = covariance[0, 0] * covariance[1, 1] - covariance[0, 1] * covariance[1, 0]
    norm = math.sqrt(drift[0] * drift[0] + drift[1] * drift[1])
    if not determinant > 0:
        return 0.0, norm
    statistic = (covariance[1, 1] * drift[0] * drift[0] - (covariance[0, 1] + covariance[1, 0]) * drift[0] * drift[1]
                 + covariance[0, 0] * drift[1] * drift[1]) / determinant
    return statistic, norm


def turn_angle(a: rot.Quaternion, b: rot.Quaternion) -> float:
    """The angle (rad, in [0, pi]) of the rotation from attitude a to attitude b."""
    return math.hypot(*rot.log(rot.multiply(rot.conjugate(a), b)))


class BiasStepDetector:
    """Sums the tilt corrections over a window: with a constant gyro bias they are white with the
    covariance sum of K S K^T; a chi-square excess of their horizontal part means the tilt keeps
    drifting one way, i.e. the bias changed (an innovation-based fault test, as the windowed
    NIS test of Bar-Shalom et al. 2001, section 5.4, applied to the state corrections), at the end
    of each window. The corrections' sum over the window is the rate the tilt drifted at: a lower
    bound of the bias change. (Tested at every step instead, the sum raised false alarms on rough
    ground, where the corrections are correlated, even at a 1e-15 probability or with a drift of
    3 deg/s required, each throwing the tilt by degrees; at the window's end it raises none.)

    A window in which the filter reopened its velocity (`disturb`: most feet disagreed at once) is
    no white sum either: after slips its corrections lean one way. Its excess counts only with a
    drift of at least `min_drift` (rad/s: the bias step the filter models), or when it is as
    improbable as two windows' in a row (the false-alarm probability squared: twice the threshold
    at 2 dof). On rough DART ground slips gave such windows 20.4 against 18.4 with a drift of
    3.6 mrad/s; a 0.5 rad/s bias step, whose slipping feet reopen the velocity ten times a window,
    gave 63 to 2,600 with drifts of 2 to 120 mrad/s; a tilt thrown by 100 deg, drifts of 20 mrad/s
    and more.

    The gyro's scale and cross-axis errors (`scale_std`, a fraction of the turn) are constant: over
    a window in which the body turned by an angle a they add up to an error of about scale_std * a
    on each axis, which no white sum holds (the filter spreads them over its steps as white noise).
    The test adds that variance, (scale_std * a)^2 per axis. On the DART course with the consumer
    IMU (3 % scale, 2 % cross-axis) windows in which the body turned by 1-3 deg gave 19-30
    against 18.4 with drifts of 3-5 mrad/s without it, 2-13 with it."""

    def __init__(self, window: float, probability: float, min_drift: float, scale_std: float):
        self.window = window
        self.threshold = chi2_quantile(probability, 2)
        self.disturbed_threshold = chi2_quantile(1.0 - (1.0 - probability)**2, 2)
        self.min_drift = min_drift
        self.scale_std = scale_std
        self._start_attitude: rot.Quaternion | None = None
        self.disturbed = False
        self.detections = 0
        self.first_detection: float | None = None    # s, times of the first and the latest detection
        self.last_detection: float | None = None
        self._start: float | None = None
        # The window's sums of corrections and of their covariances, a TILT_SUMS record which
        # `add` adds to (compiled updates add to it themselves).
        self.sums = np.zeros(1, dtype=TILT_SUMS)
        self._sum, self._covariance = self.sums[0]["correction"], self.sums[0]["covariance"]

    def add(self, correction: np.ndarray, covariance: np.ndarray) -> None:
        self._sum += correction
        self._covariance += covariance

    def disturb(self) -> None:
        """The filter reopened its velocity within this window."""
        self.disturbed = True

    def restart(self, t: float, q: rot.Quaternion) -> float:
        """Start a new window at t, attitude q; returns the length of the one it ends (0 before the first)."""
        elapsed = 0.0 if self._start is None else t - self._start
        self._start = t
        self._start_attitude = tuple(q)
        self.disturbed = False
        self._sum[:] = 0.0
        self._covariance[:] = 0.0
        return elapsed

    def check(self, t: float, q: rot.Quaternion, untested_before: float = -math.inf) -> tuple[float, float] | None:
        """None, or when the bias moved (q: the current attitude): (the tilt's drift rate over the
        window, rad/s; the window's length, s). A window that began before `untested_before` (s)
        ends untested."""
        if self._start is None:
            self.restart(t, q)
        elapsed = t - self._start
        if elapsed < self.window:
            return None
        began = self._start
        scale_error = self.scale_std * turn_angle(self._start_attitude, q)
        statistic, drift = drift_statistic(self.sums, q, scale_error**2)
        rate = drift / elapsed
        moved = statistic > self.threshold and began >= untested_before and (
            not self.disturbed or rate >= self.min_drift or statistic > self.disturbed_threshold)
        self.restart(t, q)
        if not moved:
            return None
        self.record_detection(t)
        return rate, elapsed

    def record_detection(self, t: float) -> None:
        """Count a detection at t."""
        self.detections += 1
        self.last_detection = t
        self.first_detection = t if self.first_detection is None else self.first_detection


class FusionEstimator(Estimator):
    """Front end of `ekf` and `ukf`: preintegration, time keeping, gates, leg odometry, terrain
    and the output.

    Subclasses hold the filter core: `state` (NominalState), `P` (35x35 error covariance) and the
    three methods below, which record every applied update's tilt correction
    (`_record_tilt_correction`, or `bias_steps.sums` in a compiled update). The state's arrays
    are views of the NOMINAL record `nominal` unless a subclass replaces them (the UKF does). The
    filter steps (`_step`) at every encoder sample, and every MAX_STEP without them; between steps
    each IMU sample only adds to the preintegration and the attitude it reports.
    """

    def __init__(self, params: FusionConfig, terrain: TerrainEstimatorConfig, geometry: LegGeometry,
                 foot_radius: float, gravity: float, imu_rotation: np.ndarray | None = None,
                 imu_position: np.ndarray | None = None, startup_time: float = 0.0,
                 accel_array: np.ndarray | None = None, imu_rate: float = 1000.0, accel_range: float = math.inf):
        super().__init__(imu_rotation)
        self.params = params
        self.array = _rate_tracker(params, accel_array, imu_rate, accel_range)
        self.noise = FusionNoise.from_config(params)
        self.gravity = gravity
        self.foot_radius = foot_radius
        self.imu_position = np.zeros(3) if imu_position is None else np.asarray(imu_position, dtype=float)
        self.accel_gate = chi2_quantile(params.accel_gate_probability, 3)
        self.foot_gate = chi2_quantile(params.foot_gate_probability, 3)
        self.legs = StanceTracker(geometry, params.stance_min_force, self.imu_position)
        self.still = StillWindow(params.still_window, math.radians(params.still_max_rate_dps), params.still_max_force_change)
        # White accelerometer noise averaged over the window, and what a still body still shakes.
        self._still_variance = params.accel_noise_density**2 / params.still_window + params.still_force_std**2
        # The same for the gyro. Until `startup_time` (s) the robot stands on planted feet and does
        # not turn about its z axis (the calibration poses tilt it about x and y): the mean z reading
        # of a window in which the body does not turn is then the z bias, which nothing else
        # measures as directly. Such a window needs no force test (the tilt's still windows do):
        # the accelerometer's noise over an interval (0.055 m/s^2 on the consumer part) fails it
        # in most windows.
        self._still_rate_variance = params.gyro_noise_density**2 / params.still_window + params.still_rate_std**2
        self.unturned = StillWindow(params.still_window, math.radians(params.still_max_rate_dps), math.inf)
        self.stands_until = startup_time
        self.terrain = TerrainFilter(terrain)
        self.bias_steps = BiasStepDetector(params.bias_fault_window, params.bias_fault_probability,
                                           params.bias_fault_std, params.gyro_scale_std)
        # States whose uncertainty is carried but which updates leave alone (Schmidt 1966): the
        # accelerometer offset, once the start-up poses are over (`startup_time`, s).
        self.learn_accel_bias_until = {"always": math.inf, "startup": startup_time,
                                       "never": -math.inf}[params.accel_bias_estimation]
        self.consider: slice | None = None      # set by _hold_accel_bias
        self.state: NominalState | None = None
        self.nominal = np.zeros(1, dtype=NOMINAL)
        self.P = np.zeros((ERROR_DIM, ERROR_DIM))
        self.t: float | None = None
        # The specific force gate: the squared body acceleration beyond which a sample is a spike,
        # and the body acceleration's variance.
        self.pre = Preintegration(gravity, params.spike_body_accel**2, self.noise.body_accel)
        self.rejected_accel = 0
        self.tilt_restarts = 0
        self.velocity_restarts = 0
        self.rejected_feet = 0
        self._extra = np.zeros(ERROR_DIM)
        self._accel_rejected_since: float | None = None
        self._output: tuple | None = None
        self._pose_covariances: tuple = (None, None)      # position_cov, velocity_cov of the last step
        self._output_settings = np.zeros(1, dtype=OUTPUT_SETTINGS)
        self._output_settings[0] = self.imu_position, ROLLING_STD * ROLLING_SHARE if params.rolling_feet else 0.0
        self._start_position = np.zeros(3)   # m, world: the IMU point at the start
        self._loads = np.full(NUM_FEET, np.nan)  # N, the feet's normal forces low-passed (`low_passed_loads`)
        self._loads_time: float | None = None  # s, of the last foot sample
        self._step_loads = np.zeros(NUM_FEET)  # N, as they were at the last encoder sample
        self._body_turn = np.zeros(3)        # rad, the gyro's rotation vector since the last encoder sample
        self._mean_force = np.zeros(3)       # m/s^2, the last interval's (`interval_summary`)
        self._rolled = np.zeros((NUM_FEET, 3))   # m, how far each tracked foot would roll on a sticking contact
        self._last_gyro: tuple[float, float, float] | None = None   # rad/s, the last reading
        self._gyro_repeats = 0               # how many times in a row it repeated
        self._without_gyro = 0.0             # s of this interval with the gyro missing or stuck
        # With an array: the gyro bias when the tracked rate took over from the gyro (None while
        # the gyro is read), how long ago, the bias variance its error added since the last step,
        # and the gyro's offset before its current run of repeated readings.
        self._coast_bias: np.ndarray | None = None
        self._coasted = 0.0
        self._coast_variance = 0.0
        self._offset_before_repeats = np.zeros(3)

    # -- filter core ---------------------------------------------------------------------------

    @abc.abstractmethod
    def _predict(self) -> None:
        """Move state and P over the preintegrated interval `self.pre` (dt > 0)."""

    @abc.abstractmethod
    def _correct_specific_force(self, mean_force: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        """Gravity-direction update from a step's mean specific force, noise `variance` I; applied
        only if the NIS <= gate. Returns (applied, NIS)."""

    @abc.abstractmethod
    def _correct_yaw_rate_bias(self, mean_rate: float, variance: float) -> None:
        """Zero angular rate update about the body's z axis: a standing body's mean z gyro reading
        `mean_rate` (rad/s) is the z bias, with noise `variance`."""

    @abc.abstractmethod
    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """Update of the tracked feet `legs` with their kinematics (n, 3), noise `noise.foot_position`;
        a foot whose NIS exceeds `foot_gate` is left out. Returns the (n,) mask of the feet used."""

    def _extra_noise(self) -> np.ndarray:
        """Process noise of this step beyond the white noises: the attitude variance of the gyro's
        scale and cross-axis errors over the step's turn (set in `_step`), the velocity variance of
        the specific force samples that were rejected or missing."""
        self._extra[VEL] = self.pre.extra_velocity_variance
        return self._extra

    def _record_tilt_correction(self, dtheta: np.ndarray, covariance: np.ndarray) -> None:
        """An applied update moved the attitude by dtheta, whose predicted covariance was `covariance`."""
        self.bias_steps.add(dtheta, covariance)

    # -- samples -------------------------------------------------------------------------------

    def update(self, sample: Sample) -> Estimate | None:
        # The 1 kHz path in fewer Python steps: imu_sample tests the specific force for finite values
        # itself; a gyro reading that is not finite takes the general path, which counts it as missing.
        if type(sample) is ImuSample and self.state is not None and self._body_from_imu is None:
            gyro, accel = sample.gyro, sample.accel
            # (dtypes compared by value: arrays that numba boxed carry their own float64 dtype object)
            if type(gyro) is np.ndarray and type(accel) is np.ndarray and gyro.shape == accel.shape == (3,) \
                    and gyro.dtype == FLOAT64 and accel.dtype == FLOAT64 and math.isfinite(gyro[0] + gyro[1] + gyro[2]):
                return self._update_imu(sample.t, gyro, accel)
        if type(sample) is AccelSample:
            if self.array is not None:
                self.array.add_member(sample.t, sample.index, sample.accel)
            return None
        return super().update(sample)

    def update_batch(self, samples: Iterable[Sample]) -> list[Estimate]:
        """As `update` one at a time (`batch_estimates`)."""
        return self.batch_estimates(samples if isinstance(samples, Sequence) else list(samples)).objects()

    def batch_estimates(self, samples: Sequence[Sample]) -> Estimates:
        """As `update` one at a time. Once the filter is initialised, without an accelerometer array
        or a mounting rotation, the IMU samples between two encoder samples go through one compiled
        loop (`imu_samples`); the samples it leaves or stops at go the per-sample way. The foot
        samples among them touch only the stance tracker and the loads, which only a filter step
        reads: each is applied before the next sample handled in Python. The estimates of the IMU
        samples of the compiled loop stay rows (`EstimateRows`)."""
        estimates = Estimates()
        start = 0
        while self.state is None and start < len(samples):     # the first usable IMU sample initialises
            estimates.add(super().update_batch(samples[start:start + 1]))
            start += 1
        rest = samples[start:]
        positions = [i for i, sample in enumerate(rest) if type(sample) is ImuSample]
        imu = [rest[i] for i in positions]
        readings = self._batch_readings(imu)
        if readings is None:
            estimates.add(super().update_batch(rest))
            return estimates
        batch = ImuBatch(rest, positions, readings, readings["t"].copy(), np.empty(len(imu), dtype=IMU_OUTPUTS))
        # The IMU samples with no sample but feet between them share a run.
        others_before = np.cumsum([type(sample) not in (ImuSample, FootSample) for sample in rest])
        done = 0        # samples of `rest` handled
        for first, stop in equal_runs(others_before[positions].tolist()):
            done = self._others(rest, done, positions[first], estimates)
            done = self._imu_run(batch, first, stop, done, estimates)
        self._others(rest, done, len(rest), estimates)
        return estimates

    def _others(self, samples: list[Sample], start: int, stop: int, estimates: Estimates) -> int:
        """`update` of the samples from start to stop - 1 that are not ImuSamples (those that are
        went through `imu_samples`), appending their estimates; returns stop."""
        for sample in samples[start:stop]:
            if type(sample) is not ImuSample and (estimate := self.update(sample)) is not None:
                estimates.append(estimate)
        return stop

    def _batch_readings(self, samples: list[ImuSample]) -> np.ndarray | None:
        """The IMU samples' IMU_READINGS for `imu_samples`, or None when the per-sample path must
        take them all: an accelerometer array or a mounting rotation, or readings that are not
        3-vectors."""
        if self.state is None or self.array is not None or self._body_from_imu is not None:
            return None
        stacked = stacked_readings(samples)
        if stacked is None:
            return None
        readings = np.empty(len(samples), dtype=IMU_READINGS)
        readings["gyro"], readings["accel"] = stacked
        readings["t"] = [sample.t for sample in samples]
        return readings

    def _imu_run(self, batch: ImuBatch, first: int, stop: int, done: int, estimates: Estimates) -> int:
        """Append the estimates of the batch's IMU samples first to stop - 1 through `imu_samples`,
        which hands the samples it stops at to `_end_sample` or `update` (after the foot samples
        before them); `done` of the batch's samples were handled before, returns how many are now."""
        samples, positions, readings, out = batch.samples, batch.positions, batch.readings, batch.out
        row = first
        while row < stop:
            state = self.state
            last_gyro = MISSING if self._last_gyro is None else np.array(self._last_gyro)
            count, status, self.t = imu_samples(self.pre.record, readings[row:stop], out[row:stop], self.t, last_gyro,
                                                state.position, state.velocity, self.imu_position)
            end = row + count
            taken = end if status == LEFT else end + 1      # samples preintegrated
            if taken > row:
                gyro = readings[taken - 1]["gyro"]
                self._last_gyro, self._gyro_repeats = (gyro[0], gyro[1], gyro[2]), 0
            if end > row:
                self._accel_rejected_since = None
                estimates.add(self._attitude_estimates(batch, row, end))
            if end == stop:
                break
            done = self._others(samples, done, positions[end], estimates)
            sample = samples[positions[end]]
            if status == LEFT:
                estimate = self.update(sample)
            else:
                result = out[end]
                estimate = self._end_sample(sample.t, readings[end]["accel"], status, self.pre.dt,
                                            (result["quaternion"], float(result["roll"]), float(result["pitch"]),
                                             float(result["yaw"]), result["position"], result["velocity"]))
            if estimate is not None:
                estimates.append(estimate)
            done = positions[end] + 1
            row = end + 1
        return done

    def _attitude_estimates(self, batch: ImuBatch, first: int, stop: int) -> EstimateRows:
        """`_attitude_estimate` of the batch's IMU samples first to stop - 1, as rows of their
        outputs (the step's outputs at the first, when they are not computed yet)."""
        if self._output is None:
            row, reading = batch.out[first], batch.readings[first]
            self._output = self._step_output(float(reading["t"]), float(row["roll"]), float(row["pitch"]),
                                             float(row["yaw"]), reading["gyro"])
        return EstimateRows(batch.times, batch.out, first, stop, self._output, self._pose_covariances)

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        """As Estimator's, and a reading that is not finite counts as missing too."""
        if self.state is None:
            return self._initialise(t, gyro, accel)
        dt = max(t - self.t, 0.0)
        gyro = self._gyro_input(t, gyro, dt)
        state = self.state
        status, interval, quaternion, roll, pitch, yaw, position, velocity = imu_sample_and_pose(
            self.pre.record, MISSING if gyro is None else gyro, MISSING if accel is None else accel, dt,
            state.position, state.velocity, self.imu_position)
        if dt > 0:
            self.t = t
        if status == ACCEPTED and interval < MAX_STEP:
            self._accel_rejected_since = None
            return self._attitude_estimate(t, quaternion, roll, pitch, yaw, position, velocity)
        return self._end_sample(t, accel, status, interval, (quaternion, roll, pitch, yaw, position, velocity))

    def _end_sample(self, t: float, accel: np.ndarray | None, status: int, interval: float, attitude: tuple) -> Estimate:
        """The estimate of an IMU sample already preintegrated (`imu_sample_and_pose`, giving its
        `status`, the `interval` so far and `attitude`: quaternion, roll, pitch, yaw, position,
        velocity) whose specific force was not accepted or which ended the interval: the gate's
        bookkeeping, and the filter step when the interval reached MAX_STEP."""
        nominal = False      # the sample's attitude gives way to the nominal one after a restart or a step
        if status == ACCEPTED:
            self._accel_rejected_since = None
        elif status == REJECTED and self._accel_rejected(t, accel):
            nominal = True
        if interval >= MAX_STEP:
            self._step()
            nominal = True
        if nominal:
            return self._estimate(t)
        return self._attitude_estimate(t, *attitude)

    def _gyro_input(self, t: float, gyro: np.ndarray | None, dt: float) -> np.ndarray | None:
        """The rate the filter integrates for this sample (body frame, bias included), or None.
        Without an array a stuck gyro reads as a still body and a missing one is held, the body's
        unknown rate added to the attitude's variance. With one, a healthy gyro's detected jumps
        are taken out (their estimates' error added to the bias variance); a stuck or missing gyro,
        or none at all (use_gyro = false), gives way to the tracked rate plus the bias of the
        moment it took over, and the bias state then carries the tracked rate's error, its variance
        growing as `RateTracker.coasting_variance_rate`."""
        stuck = gyro is not None and self._stuck(gyro)
        array = self.array
        if array is None:
            if stuck:
                gyro = self.state.bias
            if stuck or gyro is None:
                self._without_gyro += dt
            return gyro
        if self._gyro_repeats == 0:
            self._offset_before_repeats[:] = array.offset
        if gyro is not None and not stuck and self.params.use_gyro:
            if self._coast_bias is not None:
                self._stop_coasting(t, gyro)
            array.follow(t, gyro - self.state.bias)
            self._coast_variance += array.jump_variance
            array.jump_variance = 0.0
            return gyro - array.offset
        if self._coast_bias is None:
            # The repeated readings before the gyro counted as stuck may have passed for jumps.
            array.offset[:] = self._offset_before_repeats
            self._coast_bias = self.state.bias.copy()
            self._coasted = 0.0
        self._coasted += dt
        self._coast_variance += array.coasting_variance_rate(self._coasted) * dt
        return array.coast(t) + self._coast_bias

    def _stop_coasting(self, t: float, gyro: np.ndarray) -> None:
        """The gyro reads again: its bias is the one it had when the tracked rate took over (the
        bias state carried the tracked rate's error meanwhile); the tracked rate restarts from it."""
        self.state.bias[:] = self._coast_bias
        self._coast_bias = None
        self.array.anchor(t, gyro - self.state.bias)

    def _stuck(self, gyro: np.ndarray) -> bool:
        """Whether the reading has repeated exactly STUCK_GYRO_SAMPLES times in a row."""
        reading = (gyro[0], gyro[1], gyro[2])
        self._gyro_repeats = self._gyro_repeats + 1 if reading == self._last_gyro else 0
        self._last_gyro = reading
        return self._gyro_repeats >= STUCK_GYRO_SAMPLES

    def _accel_rejected(self, t: float, accel: np.ndarray) -> bool:
        """Count a specific force beyond the gate (integrated as gravity alone). Returns True when
        the tilt was restarted."""
        self.rejected_accel += 1
        if self._accel_rejected_since is None:
            self._accel_rejected_since = t
            return False
        if t - self._accel_rejected_since <= self.params.gate_recovery_time:
            return False
        # Rejected for too long: the filter, not the sensor, is off (its attitude was thrown by a
        # gyro fault, say). Restart the tilt from gravity as at start-up.
        self._accel_rejected_since = None
        self._step()
        self._restart_tilt(accel)
        return True

    def _step(self, new_interval: bool = True) -> None:
        """Apply the preintegrated interval to the state and its covariance; then start the next
        interval, unless the caller (`new_interval` False) corrects the state further first."""
        dt = self.pre.dt
        if dt <= 0:
            return
        mean_force = self._mean_force
        fx, fy, fz, tx, ty, tz, turn_squared = interval_summary(self.pre.record, mean_force, self._body_turn)
        self._extra[THETA] = (self.params.gyro_scale_std * math.sqrt(turn_squared))**2 \
            + (BODY_RATE_STD * self._without_gyro)**2
        self._extra[BIAS] = self._coast_variance
        self._without_gyro = self._coast_variance = 0.0
        still = self.still.add(dt, (tx, ty, tz), (fx, fy, fz), self.state.bias)
        standing = self.t < self.stands_until
        unturned = self.unturned.add(dt, (tx, ty, tz), (fx, fy, fz), self.state.bias) if standing else None
        self._predict()
        if still is not None:
            self._correct_specific_force(still.force + self.state.accel_bias, self._still_variance, self.accel_gate)
        if unturned is not None:
            self._correct_yaw_rate_bias(unturned.rate[2], self._still_rate_variance)
        if not np.count_nonzero(self.legs.tracked):     # (ndarray.any costs four times as much)
            # No leg pins the velocity: fall back on the gravity direction of the step's mean
            # specific force. Walking accelerations last longer than a step, so averaging over the
            # step does not reduce their variance: a weak reference, for long leg outages.
            self._correct_specific_force(mean_force + self.state.accel_bias, self.noise.body_accel, self.accel_gate)
        # The poses' tilt corrections (the gyro's scale errors over their turns) are no bias step:
        # windows that began while the robot stood are not tested.
        moved = self.bias_steps.check(self.t, self.state.q, self.stands_until)
        if moved is not None:
            self._open_bias(np.array(rot.up_in_body(self.state.q)), *moved)
        if self.consider is None and self.t >= self.learn_accel_bias_until:
            self._hold_accel_bias()
        if new_interval:
            self._new_interval()

    def _hold_accel_bias(self) -> None:
        """The start-up poses are over (or there are none to learn from, "never"): the
        accelerometer offset and cross-axis terms become consider states, the offset's
        variance widened by the stance feet's creep acceleration, which aliases into the tilt
        exactly as an offset does."""
        self.consider = ACCEL_ERRORS
        self.P[ACCEL_BIAS, ACCEL_BIAS] += self.params.foot_creep_accel_std**2 * np.eye(3)

    def _new_interval(self) -> None:
        """Preintegrate from the nominal state as it is now (after a step and its updates)."""
        self.pre.start(self.state.q, self.state.bias, self.state.accel_bias)
        self._output = None

    def _open_bias(self, up: np.ndarray, drift_rate: float, elapsed: float) -> None:
        """The gyro bias moved, by at least the tilt's drift rate over the detection window
        (`elapsed` long): widen its uncertainty by that rate (bias_fault_std at least), and the
        tilt's by the drift such a change may have caused over the window, in the horizontal
        directions (`up`: the up direction, body frame). The test sees the bias's horizontal part
        only; a step moves the vertical part as likely, which the feet then teach."""
        step = max(self.params.bias_fault_std, drift_rate)
        drift = step * elapsed
        horizontal = np.eye(3) - np.outer(up, up)
        self.P[BIAS, BIAS] += step**2 * np.eye(3)
        self.P[THETA, THETA] += drift**2 * horizontal

    def _initialise(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if accel is None or not np.linalg.norm(accel) > 0:
            return None
        roll, pitch = rot.tilt_from_specific_force(*accel)
        q = rot.quaternion_from_euler(roll, pitch, 0.0)
        self.nominal[0] = np.zeros((), dtype=NOMINAL)
        fields = self.nominal[0]
        self.state = NominalState(q, fields["bias"], fields["velocity"], fields["accel_bias"], fields["feet"],
                                  fields["accel_cross"], fields["position"])
        self.state.position[:] = rot.to_matrix(q) @ self.imu_position      # the body origin starts at 0
        self._start_position = self.state.position.copy()
        self.P = initial_covariance(self.params, q)
        self.t = t
        if t >= self.learn_accel_bias_until:
            self._hold_accel_bias()
        self.pre.remember(gyro if self.params.use_gyro else None, accel)
        self._new_interval()
        return self._estimate(t)

    def _restart_tilt(self, accel: np.ndarray) -> None:
        """Roll and pitch from this specific force, with the start-up uncertainty; yaw is kept."""
        old_up = np.array(rot.up_in_body(self.state.q))
        yaw_variance = float(old_up @ self.P[THETA, THETA] @ old_up)
        _, _, yaw = rot.euler_from_quaternion(self.state.q)
        self.state.q = rot.quaternion_from_euler(*rot.tilt_from_specific_force(*accel), yaw)
        up = np.array(rot.up_in_body(self.state.q))
        self.P[THETA, :] = 0.0
        self.P[:, THETA] = 0.0
        tilt = math.radians(self.params.initial_tilt_std_deg)
        self.P[THETA, THETA] = tilt**2 * (np.eye(3) - np.outer(up, up)) + yaw_variance * np.outer(up, up)
        self._restart_velocity()
        self.tilt_restarts += 1
        self._new_interval()

    def _update_feet(self, sample: FootSample) -> None:
        self.legs.add_contacts(sample.contact, sample.normal_forces)     # (checks the forces' shape)
        elapsed = 0.0 if self._loads_time is None else sample.t - self._loads_time
        self._loads = low_passed_loads(self._loads, np.asarray(sample.normal_forces, dtype=float), elapsed,
                                       self.params.foot_load_time_constant)
        self._loads_time = sample.t

    def _update_encoders(self, sample: EncoderSample) -> None:
        if self.state is None:
            return
        self._step(new_interval=False)      # the next interval starts from the state the feet correct
        rolling = None
        if self.params.rolling_feet:
            self._rolled[:] = 0.0
            rolling = (self._rolled, self._body_turn, ground_normal_in_body(self.terrain.x, self.state.q),
                       self.foot_radius)
        reading = self.legs.read(sample.positions, rolling)
        if rolling is not None:
            self._body_turn[:] = 0.0
            roll_feet(self.P, self.state.feet, self._rolled, ROLLING_FRACTION, ROLLING_STD)
        if (self.params.foot_sink_per_newton > 0 or self.params.foot_shear_per_newton > 0) and len(reading.tracked):
            sink_feet(self.P, reading.tracked, self._loads, self._step_loads, rot.up_in_body(self.state.q),
                      self.params.foot_sink_per_newton, self.params.foot_shear_per_newton)
        self._step_loads = self._loads
        measured, restart = reading.measured, reading.new
        if len(reading.tracked):
            used = self._correct_feet(reading.tracked, measured.take(reading.tracked, axis=0))
            if np.count_nonzero(used) < len(used):
                # A foot whose kinematics disagree slipped (or read badly): start it again. When most
                # of them disagree, the filter's velocity is wrong instead: reopen it too.
                rejected = reading.tracked[~used]
                self.rejected_feet += len(rejected)
                restart = np.concatenate([restart, rejected])
                if len(rejected) > len(used) // 2:
                    self._restart_velocity()
        for leg in restart.tolist():
            self._restart_foot(leg, measured[leg])
        self.terrain.add_feet(sample.t, reading.feet, reading.measurable, self.state.q, self.params.foot_position_std,
                              self.foot_radius)
        self._new_interval()

    def _restart_velocity(self) -> None:
        self.P[VEL, :] = 0.0
        self.P[:, VEL] = 0.0
        self.P[VEL, VEL] = self.params.initial_velocity_std**2 * np.eye(3)
        self.velocity_restarts += 1
        self.bias_steps.disturb()

    def _restart_foot(self, leg: int, measured: np.ndarray) -> None:
        """A new foothold: its position is the kinematics, uncorrelated with the rest."""
        self.state.feet[leg] = measured
        block = foot(leg)
        self.P[block, :] = 0.0
        self.P[:, block] = 0.0
        self.P[block, block] = self.noise.foot_position * np.eye(3)
        self.legs.tracked[leg] = True

    # -- output --------------------------------------------------------------------------------

    def _estimate(self, t: float) -> Estimate:
        """The estimate with the nominal attitude and the pose now (`current_pose`)."""
        state = self.state
        q = state.q
        return self._attitude_estimate(t, np.array(q), *rot.euler_from_quaternion(q),
                                       *current_pose(self.pre.record, state.position, state.velocity,
                                                     self.imu_position))

    def _attitude_estimate(self, t: float, quaternion: np.ndarray, roll: float, pitch: float, yaw: float,
                           position: np.ndarray, velocity: np.ndarray) -> Estimate:
        """The estimate with this attitude (quaternion x, y, z, w; roll, pitch, yaw) and pose; its
        covariance, the bias and the terrain of the last step (they change little within a step,
        and are recomputed only there)."""
        if self._output is None:
            self._output = self._step_output(t, roll, pitch, yaw, self.pre.last_gyro)
        return Estimate(t, quaternion, roll, pitch, yaw, *self._output, position, velocity, *self._pose_covariances)

    def _step_output(self, t: float, roll: float, pitch: float, yaw: float, last_gyro: np.ndarray) -> tuple:
        """The outputs recomputed at each step (they change little within one), at the sample of
        time t, attitude (roll, pitch, yaw) and gyro reading `last_gyro` (the rate the filter
        integrated, bias included): the attitude covariance, the bias and the terrain; the pose
        covariances go to `_pose_covariances`."""
        state, terrain = self.state, self.terrain
        if terrain.x is None:
            terrain_angles, growth = (None, None, None), NO_TERRAIN
        else:
            terrain_roll, terrain_pitch, height, covariance, rate = terrain.heading_output(yaw)
            terrain_angles = terrain_roll, terrain_pitch, height
            growth = TerrainGrowth(covariance, rate, max(0.0, t - terrain.t))
        attitude_cov, bias, bias_cov, terrain_cov, position_cov, velocity_cov = step_covariances(
            self.P, StepState(state.q, state.velocity, state.bias, state.position, self._start_position, last_gyro),
            self._output_settings, roll, pitch, growth)
        self._pose_covariances = position_cov, velocity_cov
        return attitude_cov, bias, bias_cov, *terrain_angles, None if terrain.x is None else terrain_cov


class StepState(NamedTuple):
    """The nominal state a step's outputs are computed from (`step_covariances`)."""
    q: rot.Quaternion
    velocity: np.ndarray        # (3,) m/s, IMU point, body frame
    gyro_bias: np.ndarray       # (3,) rad/s
    position: np.ndarray        # (3,) m, IMU point, world frame
    start_position: np.ndarray  # (3,) m, the IMU point at the start
    last_gyro: np.ndarray       # (3,) rad/s, the last gyro reading (bias included)


class TerrainGrowth(NamedTuple):
    """The terrain output's covariance at its last update, its growth per second, and the time
    since that update (s): `grown_covariance`'s inputs."""
    covariance: np.ndarray
    rate: np.ndarray
    elapsed: float


NO_TERRAIN = TerrainGrowth(ZERO33, ZERO33, 0.0)     # before the first support plane

# The estimator's constants that its step outputs read, fields by name (`step_covariances`): the
# lever arm of the IMU point (m, body frame) and the std of the position's scale error per metre
# walked (0 without rolling feet; module docstring).
OUTPUT_SETTINGS = np.dtype([("lever", "f8", 3), ("scale_error", "f8")])


# Compiled: one call per filter step for all of its covariance outputs.
@njit(cache=True)
def step_covariances(P: np.ndarray, state: StepState, settings: np.ndarray, roll: float, pitch: float,
                     terrain: TerrainGrowth) -> tuple:
    """(attitude_cov, gyro bias, its covariance, terrain covariance, position_cov, velocity_cov),
    new arrays: `output_covariances` at the attitude (roll, pitch) and `pose_covariances` of the
    nominal state, the position's widened by the rolling feet's scale error along the horizontal
    distance walked (ROLLING_SHARE, module docstring), with the OUTPUT_SETTINGS record `settings`."""
    s = settings[0]
    rate = state.last_gyro - state.gyro_bias
    position_cov, velocity_cov = pose_covariances(P, state.q, state.velocity, rate, s.lever)
    if s.scale_error > 0.0:
        walked = state.position - state.start_position
        walked[2] = 0.0         # the spheres roll along the ground
        scale_error = s.scale_error * walked      # m, std of the position's scale error
        for i in range(3):
            for j in range(3):
                position_cov[i, j] += scale_error[i] * scale_error[j]
    attitude_cov, bias, bias_cov, terrain_cov = output_covariances(P, state.gyro_bias, roll, pitch, terrain.covariance,
                                                                   terrain.rate, terrain.elapsed)
    return attitude_cov, bias, bias_cov, terrain_cov, position_cov, velocity_cov


# Compiled: it runs at every filter step.
@njit(cache=True)
def interval_summary(record: np.ndarray, mean_force: np.ndarray, body_turn: np.ndarray) -> tuple:
    """The mean specific force of the interval preintegrated in `record`, written into
    `mean_force`, and the gyro's rotation vector (without the filter's corrections), added to
    `body_turn`. Returns both (x, y, z each) and turn . turn."""
    p = record[0]
    mean_force[:] = p.dv / p.dt
    turn = np.array(rot.log((p.dq[0], p.dq[1], p.dq[2], p.dq[3])))
    body_turn += turn
    return mean_force[0], mean_force[1], mean_force[2], turn[0], turn[1], turn[2], turn @ turn


# Compiled: one call per IMU sample.
@njit(cache=True)
def imu_sample_and_pose(record: np.ndarray, gyro: np.ndarray, accel: np.ndarray, dt: float, position: np.ndarray,
                        velocity: np.ndarray, lever: np.ndarray) -> tuple:
    """`imu_sample` of readings that are missing where they are not finite (MISSING), then
    `current_pose` of the nominal IMU-point position and velocity with the lever arm:
    (status, the interval preintegrated so far (s), the attitude now as a quaternion array
    (x, y, z, w), roll, pitch, yaw, position, velocity)."""
    status, qx, qy, qz, qw, roll, pitch, yaw = imu_sample(record, gyro, accel, dt)
    position_now, velocity_now = current_pose(record, position, velocity, lever)
    return status, record[0].dt, np.array((qx, qy, qz, qw)), roll, pitch, yaw, position_now, velocity_now


# IMU samples in time order, one element each (body frame): `imu_samples`' input.
IMU_READINGS = np.dtype([("t", "f8"), ("gyro", "f8", 3), ("accel", "f8", 3)])     # s, rad/s, m/s^2

# `imu_sample_and_pose`'s attitude and pose of each sample: `imu_samples`' output, the rows of
# the estimates of a run of IMU samples.
IMU_OUTPUTS = ESTIMATE_ROWS

LEFT = -1      # `imu_samples`' status of a sample it left untouched


class ImuBatch(NamedTuple):
    """`FusionEstimator.batch_estimates`' samples and the IMU samples among them, in order."""
    samples: list[Sample]
    positions: list[int]       # where the IMU samples are in `samples`
    readings: np.ndarray       # IMU_READINGS of the IMU samples
    times: np.ndarray          # s, their times
    out: np.ndarray            # IMU_OUTPUTS of the IMU samples, as `imu_samples` writes them (the estimates' rows)


# Compiled: one call per run of IMU samples between two other samples (offline replay).
@njit(cache=True)
def imu_samples(record: np.ndarray, readings: np.ndarray, out: np.ndarray, t: float, last_gyro: np.ndarray,
                position: np.ndarray, velocity: np.ndarray, lever: np.ndarray) -> tuple:
    """`imu_sample_and_pose` of the IMU_READINGS `readings` in order, each at the interval since
    the previous sample (the first since time t, whose gyro read `last_gyro`), from the nominal
    position and velocity with the lever arm, each sample's attitude and pose written into the
    same element of the IMU_OUTPUTS `out`. Stops before a sample whose reading is not finite or
    whose gyro repeats the previous reading (the stuck gyro's count), and after a sample whose
    specific force was not accepted or which brought the interval to MAX_STEP. Returns (the index
    it stopped at, that sample's status: LEFT when untouched, the time of the last sample
    preintegrated)."""
    previous = last_gyro.copy()
    for i in range(len(readings)):
        reading = readings[i]
        gyro, accel = reading.gyro, reading.accel
        if not (math.isfinite(gyro[0] + gyro[1] + gyro[2]) and math.isfinite(accel[0] + accel[1] + accel[2])) \
                or (gyro[0] == previous[0] and gyro[1] == previous[1] and gyro[2] == previous[2]):
            return i, LEFT, t
        dt = max(reading.t - t, 0.0)
        status, interval, quaternion, roll, pitch, yaw, pose_position, pose_velocity = imu_sample_and_pose(
            record, gyro, accel, dt, position, velocity, lever)
        if dt > 0:
            t = reading.t
        row = out[i]
        row.quaternion[:] = quaternion
        row.roll, row.pitch, row.yaw = roll, pitch, yaw
        row.position[:] = pose_position
        row.velocity[:] = pose_velocity
        previous[:] = gyro
        if status != ACCEPTED or interval >= MAX_STEP:
            return i, status, t
    return len(readings), LEFT, t


def equal_runs(values: list[int]) -> list[tuple[int, int]]:
    """The (first, stop) index ranges of `values` over which the value stays the same."""
    if not values:
        return []
    edges = [0, *(np.flatnonzero(np.diff(values)) + 1).tolist(), len(values)]
    return list(zip(edges[:-1], edges[1:]))


# Compiled: it runs at every filter step, on 3x3 blocks where numpy's per-call cost dominates.
@njit(cache=True)
def output_covariances(P: np.ndarray, bias: np.ndarray, roll: float, pitch: float, terrain_cov: np.ndarray,
                       terrain_growth: np.ndarray, elapsed: float) -> tuple:
    """(attitude_cov (roll, pitch, yaw), gyro bias, its covariance, terrain covariance): the
    output's arrays, new, from the error covariance P and the terrain's covariance at its last
    update, grown over `elapsed`."""
    euler = rot.euler_jacobian(roll, pitch)
    attitude_cov = rot.matmul3(rot.matmul3(euler, P[0:3, 0:3]), euler.T)
    return (attitude_cov, bias.copy(), np.ascontiguousarray(P[3:6, 3:6]),
            grown_covariance(terrain_cov, terrain_growth, elapsed, attitude_cov[:2, :2]))


# Compiled: it runs at every IMU sample.
@njit(cache=True)
def current_pose(record: np.ndarray, position: np.ndarray, velocity: np.ndarray, lever: np.ndarray) -> tuple:
    """(position, velocity) of the body origin in the world now, at the last sample of the
    interval preintegrated in `record`, from the nominal IMU-point position r (world) and velocity v
    (body) at its start (`apply_preintegration`'s model, and o = r - R l, v_o = R (v - w x l) with the
    lever arm l and the body rate w, gyro minus bias)."""
    p = record[0]
    dt, gravity = p.dt, p.gravity
    q0 = (p.q0[0], p.q0[1], p.q0[2], p.q0[3])
    R0 = rot.to_matrix(q0)
    up = np.array(rot.up_in_body(q0))
    imu_point = position + rot.matvec3(R0, velocity * dt + p.dp)
    imu_point[2] -= 0.5 * gravity * dt * dt
    body_velocity = rot.matvec3(rot.to_matrix((p.dq[0], p.dq[1], p.dq[2], p.dq[3])).T,
                                velocity - gravity * dt * up + p.dv)
    rate = p.last_gyro - p.gyro_bias
    R = rot.matmul3(R0, rot.to_matrix((p.dq[0], p.dq[1], p.dq[2], p.dq[3])))
    return (imu_point - rot.matvec3(R, lever),
            rot.matvec3(R, body_velocity - rot.matvec3(rot.skew(rate), lever)))


# Compiled: it runs at every filter step.
@njit(cache=True)
def pose_covariances(P: np.ndarray, q: rot.Quaternion, velocity: np.ndarray, rate: np.ndarray,
                     lever: np.ndarray) -> tuple:
    """(position_cov, velocity_cov) of the body origin in the world (`current_pose`), from the
    IMU point's velocity v (body), the body rate w and the lever arm l:
        do = dr + R [l]x dtheta,     dv_o = R dv - R [v - w x l]x dtheta   (rate error neglected)
    J P J^T over the (dtheta, dv, dr) blocks of P."""
    R = rot.to_matrix(q)
    body_velocity = velocity - rot.matvec3(rot.skew(rate), lever)
    theta, vel, pos = P[0:3, 0:3], P[6:9, 6:9], P[POSITION0:POSITION0 + 3, POSITION0:POSITION0 + 3]
    lever_turn = rot.matmul3(R, rot.skew(lever))
    cross = rot.matmul3(lever_turn, np.ascontiguousarray(P[0:3, POSITION0:POSITION0 + 3]))
    position_cov = pos + cross + cross.T + rot.matmul3(rot.matmul3(lever_turn, theta), lever_turn.T)
    J_v, J_theta = R, -rot.matmul3(R, rot.skew(body_velocity))
    mixed = rot.matmul3(rot.matmul3(J_v, np.ascontiguousarray(P[6:9, 0:3])), J_theta.T)
    velocity_cov = (rot.matmul3(rot.matmul3(J_v, vel), J_v.T) + mixed + mixed.T
                    + rot.matmul3(rot.matmul3(J_theta, theta), J_theta.T))
    return position_cov, velocity_cov


def ground_normal_in_body(terrain: np.ndarray | None, q: rot.Quaternion) -> tuple[float, float, float]:
    """The unit normal of the terrain plane z = a x + b y + c (`terrain` = (a, b, height), levelled
    axes; estimators/terrain.py) in the body frame of attitude q; gravity's up before any plane.
    The planted spheres roll on it (estimators/leg_odometry.py)."""
    if terrain is None:
        return rot.up_in_body(q)
    a, b = float(terrain[0]), float(terrain[1])
    scale = 1.0 / math.sqrt(1.0 + a * a + b * b)
    x, y, z = rot.to_matrix(q).tolist()     # R^T (-a, -b, 1): the world normal's components on the body axes
    return tuple((z[i] - a * x[i] - b * y[i]) * scale for i in range(3))


# Compiled: it runs at every encoder sample.
@njit(cache=True)
def roll_feet(P: np.ndarray, feet: np.ndarray, rolled: np.ndarray, fraction: float, fraction_std: float) -> None:
    """The tracked feet roll by `fraction` (k) of `rolled` (s_i, zero for the others), in place,
    and their variances grow by (fraction_std s_i)^2 per axis (module docstring)."""
    for leg in range(NUM_FEET):
        for i in range(3):
            shift = rolled[leg, i]
            if shift != 0.0:
                feet[leg, i] += fraction * shift
                r = FOOT0 + 3 * leg + i
                P[r, r] += (fraction_std * shift)**2


def _rate_tracker(params: FusionConfig, positions: np.ndarray | None, imu_rate: float,
                  accel_range: float) -> RateTracker | None:
    """The tracker of the accelerometer array at `positions` (body frame), whose members read up to
    +-`accel_range`, or None without a usable array; use_gyro = false needs one."""
    tracker = None
    if positions is not None and len(positions):
        try:
            tracker = RateTracker(AccelArrayFit(positions), params.gyro_noise_density, params.accel_noise_density,
                                  params.accel_bias_initial_std, imu_rate, accel_range)
        except ValueError:
            tracker = None
    if tracker is None and not params.use_gyro:
        raise ConfigError("estimators.ekf.use_gyro = false needs an accelerometer array spread along two "
                          "directions at least (sensors.accel_array.layout = quad or custom)")
    return tracker


# Compiled: it runs at every foot sample.
@njit(cache=True)
def low_passed_loads(smoothed: np.ndarray, loads: np.ndarray, elapsed: float, time_constant: float) -> np.ndarray:
    """The feet's loads `smoothed` (N) moved towards the new readings `loads` by a first-order
    low-pass of `time_constant` (s) over `elapsed` (s): what moves a planted foot is the load
    transfer, not the contact's ringing from one sample to the next. A reading that is not finite
    leaves its load as it was; a load not yet known (NaN) takes the reading."""
    weight = 1.0 if time_constant <= 0 else -math.expm1(-elapsed / time_constant)
    moved = smoothed.copy()
    for leg in range(loads.shape[0]):
        load = loads[leg]
        if not math.isfinite(load):
            continue
        if math.isnan(moved[leg]) or weight == 1.0:
            moved[leg] = load
        else:
            moved[leg] += weight * (load - moved[leg])
    return moved


# Compiled: it runs at every encoder sample.
@njit(cache=True)
def sink_feet(P: np.ndarray, legs: np.ndarray, loads: np.ndarray, previous_loads: np.ndarray, up: tuple,
              sink_per_newton: float, shear_per_newton: float) -> None:
    """A planted foot moves as its load changes: it sinks into the ground as it takes load and
    rises as it sheds it, and slides along the ground as its contact's tangential spring loads
    and slips. The tracked `legs`' variances grow by (sink_per_newton * load change)^2 along `up`
    (body frame) and (shear_per_newton * load change)^2 across it, in place (a load that is not
    finite changes nothing)."""
    for k in range(legs.shape[0]):
        leg = legs[k]
        change = loads[leg] - previous_loads[leg]
        if not math.isfinite(change):
            continue
        sink = (sink_per_newton * change)**2
        shear = (shear_per_newton * change)**2
        b = FOOT0 + 3 * leg
        for i in range(3):
            P[b + i, b + i] += shear
            for j in range(3):
                P[b + i, b + j] += (sink - shear) * up[i] * up[j]
