"""IMU + leg-kinematics fusion: the models shared by `ekf` and `ukf`, and their common front end.

Nominal state: attitude q (world_from_body), gyro bias b_g, accelerometer bias b_a, the
accelerometer z axis's cross-axis terms c (its reading per unit body x and y specific force), the
IMU point's velocity v and the six foot positions p_i relative to the IMU point, all in the body
frame (robocentric, so that yaw never enters). Error state (32): dx = [dtheta (local rotation
vector), db_g, dv, db_a, dc, dp_1 ... dp_6] (Sola 2017, "Quaternion kinematics for the
error-state Kalman filter", sections 5 and 6; foot states as in Bloesch et al. 2012, "State
Estimation for Legged Robots - Consistent Fusion of Leg Kinematics and IMU", kept in the body
frame).

The IMU drives the prediction (strapdown: the specific force is an input, not a measurement),
summed between filter steps by `preintegration` (Forster et al. 2017). Over an interval dt from
step i to step j, with u = R^T e_z the up direction in the body frame:
    R_j  = R_i dR
    v_j  = dR^T (v_i - g u_i dt + dv)
    p_j  = dR^T (p_i - v_i dt + g u_i dt^2 / 2 - dp)     a stance foot is fixed in the world
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
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.extending import register_jitable

from testbed.model import spatial as rot
from estimators.base import Estimate, Estimator
from estimators.config import FusionConfig, TerrainEstimatorConfig
from estimators.gating import chi2_quantile
from estimators.leg_odometry import StanceTracker
from estimators.stillness import StillWindow
from estimators.preintegration import ACCEPTED, REJECTED, Preintegration, imu_sample
from estimators.terrain import TerrainFilter, grown_covariance
from sensors.samples import EncoderSample, FootSample, ImuSample, Sample
from testbed.model.kinematics import LegGeometry

NUM_FEET = 6
FOOT0 = 14                     # error-state index of the first foot
ERROR_DIM = FOOT0 + 3 * NUM_FEET
THETA, BIAS, VEL, ACCEL_BIAS = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
ACCEL_CROSS = slice(12, 14)    # the accelerometer z axis's sensitivity to the x and y specific force
ACCEL_ERRORS = slice(9, 14)    # offset and cross-axis terms: the consider block after the start-up
FEET = slice(FOOT0, ERROR_DIM)

VELOCITY_RANDOM_WALK = 1e-3    # m/s/sqrt(s): unmodelled accelerometer errors (scale, cross-axis, vibration)
MAX_STEP = 0.01                # s: without encoder samples, the filter steps on its own this often
ZERO = np.zeros(3)
ZERO33 = np.zeros((3, 3))
FLOAT64 = np.dtype(np.float64)


def foot(leg: int) -> slice:
    """The error-state slice of foot `leg`."""
    return slice(FOOT0 + 3 * leg, FOOT0 + 3 + 3 * leg)


# The arrays of a nominal state, fields by name: the EKF's state lives in one such record, which
# its compiled feet update injects into (`FusionEstimator.nominal`).
NOMINAL = np.dtype([("bias", "f8", 3), ("velocity", "f8", 3), ("accel_bias", "f8", 3), ("accel_cross", "f8", 2),
                    ("feet", "f8", (NUM_FEET, 3))])

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


def apply_preintegration(state: NominalState, pre: Preintegration, gravity: float) -> tuple[NominalState, np.ndarray]:
    """The nominal state after the preintegrated interval; also returns dR (3x3)."""
    dt = pre.dt
    up = np.array(rot.up_in_body(state.q))
    turn = rot.to_matrix(tuple(pre.dq))
    velocity = (state.velocity - gravity * dt * up + pre.dv) @ turn
    feet = (state.feet - (state.velocity * dt - 0.5 * gravity * dt * dt * up + pre.dp)) @ turn
    q = rot.normalized(rot.multiply(state.q, tuple(pre.dq)))
    return NominalState(q, state.bias, velocity, state.accel_bias, feet, state.accel_cross), turn


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
        rates[FEET] = self.foot_slip * dt       # the cross-axis terms are constants
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


def inject_in_place(state: NominalState, dx: np.ndarray) -> None:
    """inject, modifying `state` and its arrays (the EKF's path)."""
    state.q = inject_arrays(state.q, dx, state.bias, state.velocity, state.accel_bias, state.accel_cross, state.feet)


# Compiled: the EKF's feet update calls it from its kernel.
@njit(cache=True)
def inject_arrays(q: rot.Quaternion, dx: np.ndarray, bias: np.ndarray, velocity: np.ndarray, accel_bias: np.ndarray,
                  accel_cross: np.ndarray, feet: np.ndarray) -> rot.Quaternion:
    """inject into the nominal state's arrays, in place; returns the new attitude."""
    bias += dx[BIAS]
    velocity += dx[VEL]
    accel_bias += dx[ACCEL_BIAS]
    accel_cross += dx[ACCEL_CROSS]
    feet += dx[FEET].reshape(NUM_FEET, 3)
    return rot.rotate_by_vector(q, dx[0], dx[1], dx[2])


def inject(state: NominalState, dx: np.ndarray) -> NominalState:
    """x_true = x (+) dx (Sola 2017, section 6.2)."""
    return NominalState(rot.rotate_by_vector(state.q, dx[0], dx[1], dx[2]), state.bias + dx[BIAS],
                        state.velocity + dx[VEL], state.accel_bias + dx[ACCEL_BIAS],
                        state.feet + dx[FEET].reshape(NUM_FEET, 3), state.accel_cross + dx[ACCEL_CROSS])


def horizontal_basis(up: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane perpendicular to `up`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(up, helper)
    first /= np.linalg.norm(first)
    return np.array([first, np.cross(up, first)])


class BiasStepDetector:
    """Sums the tilt corrections over a window: with a constant gyro bias they are white with the
    covariance sum of K S K^T; a chi-square excess of their horizontal part means the tilt keeps
    drifting one way, i.e. the bias changed (an innovation-based fault test, as the windowed
    NIS test of Bar-Shalom et al. 2001, section 5.4, applied to the state corrections)."""

    def __init__(self, window: float, probability: float):
        self.window = window
        self.threshold = chi2_quantile(probability, 2)
        self.detections = 0
        self._start: float | None = None
        # The window's sums of corrections and of their covariances, a TILT_SUMS record which
        # `add` adds to (compiled updates add to it themselves).
        self.sums = np.zeros(1, dtype=TILT_SUMS)
        self._sum, self._covariance = self.sums[0]["correction"], self.sums[0]["covariance"]

    def add(self, correction: np.ndarray, covariance: np.ndarray) -> None:
        self._sum += correction
        self._covariance += covariance

    def check(self, t: float, q: rot.Quaternion) -> bool:
        """At the end of each window: True when the bias moved (q: the current attitude)."""
        if self._start is None:
            self._start = t
        if t - self._start < self.window:
            return False
        basis = horizontal_basis(np.array(rot.up_in_body(q)))
        drift = basis @ self._sum
        covariance = basis @ self._covariance @ basis.T
        moved = bool(np.linalg.det(covariance) > 0 and drift @ np.linalg.solve(covariance, drift) > self.threshold)
        self._start = t
        self._sum[:] = 0.0
        self._covariance[:] = 0.0
        self.detections += moved
        return moved


class FusionEstimator(Estimator):
    """Front end of `ekf` and `ukf`: preintegration, time keeping, gates, leg odometry, terrain
    and the output.

    Subclasses hold the filter core: `state` (NominalState), `P` (30x30 error covariance) and the
    three methods below, which record every applied update's tilt correction
    (`_record_tilt_correction`, or `bias_steps.sums` in a compiled update). The state's arrays
    are views of the NOMINAL record `nominal` unless a subclass replaces them (the UKF does). The
    filter steps (`_step`) at every encoder sample, and every MAX_STEP without them; between steps
    each IMU sample only adds to the preintegration and the attitude it reports.
    """

    def __init__(self, params: FusionConfig, terrain: TerrainEstimatorConfig, geometry: LegGeometry,
                 foot_radius: float, gravity: float, imu_rotation: np.ndarray | None = None,
                 imu_position: np.ndarray | None = None, startup_time: float = 0.0):
        super().__init__(imu_rotation)
        self.params = params
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
        self.terrain = TerrainFilter(terrain)
        self.bias_steps = BiasStepDetector(params.bias_fault_window, params.bias_fault_probability)
        # States whose uncertainty is carried but which updates leave alone (Schmidt 1966): the
        # accelerometer offset, once the start-up poses are over (`startup_time`, s).
        self.learn_accel_bias_until = {"always": math.inf, "startup": startup_time,
                                       "never": -math.inf}[params.accel_bias_estimation]
        self.consider: slice | None = None      # set by _hold_accel_bias
        self.state: NominalState | None = None
        self.nominal = np.zeros(1, dtype=NOMINAL)
        self.P = np.zeros((ERROR_DIM, ERROR_DIM))
        self.t: float | None = None
        # The specific force gate: the squared body acceleration beyond which a sample is an
        # outlier, and the body acceleration's variance.
        self.pre = Preintegration(gravity, self.accel_gate * self.noise.body_accel, self.noise.body_accel)
        self.rejected_accel = 0
        self.tilt_restarts = 0
        self.velocity_restarts = 0
        self.rejected_feet = 0
        self._extra = np.zeros(ERROR_DIM)
        self._accel_rejected_since: float | None = None
        self._output: tuple | None = None
        self._body_turn = np.zeros(3)        # rad, the gyro's rotation vector since the last encoder sample
        self._mean_force = np.zeros(3)       # m/s^2, the last interval's (`interval_summary`)

    # -- filter core ---------------------------------------------------------------------------

    @abc.abstractmethod
    def _predict(self) -> None:
        """Move state and P over the preintegrated interval `self.pre` (dt > 0)."""

    @abc.abstractmethod
    def _correct_specific_force(self, mean_force: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        """Gravity-direction update from a step's mean specific force, noise `variance` I; applied
        only if the NIS <= gate. Returns (applied, NIS)."""

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
        # The 1 kHz path in fewer Python steps: imu_sample tests the readings for finite values itself.
        if type(sample) is ImuSample and self.state is not None and self._body_from_imu is None:
            gyro, accel = sample.gyro, sample.accel
            # (dtypes compared by value: arrays that numba boxed carry their own float64 dtype object)
            if type(gyro) is np.ndarray and type(accel) is np.ndarray and gyro.shape == accel.shape == (3,) \
                    and gyro.dtype == FLOAT64 and accel.dtype == FLOAT64:
                return self._update_imu(sample.t, gyro, accel)
        return super().update(sample)

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        """As Estimator's, and a reading that is not finite counts as missing too."""
        if self.state is None:
            return self._initialise(t, gyro, accel)
        dt = t - self.t
        status, qx, qy, qz, qw, roll, pitch, yaw = imu_sample(
            self.pre.record, ZERO if gyro is None else gyro, ZERO if accel is None else accel, gyro is not None,
            accel is not None, max(dt, 0.0))
        if dt > 0:
            self.t = t
        nominal = False      # the sample's attitude gives way to the nominal one after a restart or a step
        if status == ACCEPTED:
            self._accel_rejected_since = None
        elif status == REJECTED and self._accel_rejected(t, accel):
            nominal = True
        if self.pre.dt >= MAX_STEP:
            self._step()
            nominal = True
        if nominal:
            return self._estimate(t)
        return self._attitude_estimate(t, qx, qy, qz, qw, roll, pitch, yaw)

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
        self._extra[THETA] = (self.params.gyro_scale_std * math.sqrt(turn_squared))**2
        still_force = self.still.add(dt, (tx, ty, tz), (fx, fy, fz))
        self._predict()
        if still_force is not None:
            self._correct_specific_force(still_force + self.state.accel_bias, self._still_variance, self.accel_gate)
        if not np.count_nonzero(self.legs.tracked):     # (ndarray.any costs four times as much)
            # No leg pins the velocity: fall back on the gravity direction of the step's mean
            # specific force. Walking accelerations last longer than a step, so averaging over the
            # step does not reduce their variance: a weak reference, for long leg outages.
            self._correct_specific_force(mean_force + self.state.accel_bias, self.noise.body_accel, self.accel_gate)
        if self.bias_steps.check(self.t, self.state.q):
            self._open_bias(np.array(rot.up_in_body(self.state.q)))
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

    def _open_bias(self, up: np.ndarray) -> None:
        """The gyro bias moved: widen its uncertainty, and the tilt's by the drift it may have
        caused over a detection window."""
        step = self.params.bias_fault_std
        drift = step * self.bias_steps.window
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
                                  fields["accel_cross"])
        self.P = initial_covariance(self.params, q)
        self.t = t
        if t >= self.learn_accel_bias_until:
            self._hold_accel_bias()
        self.pre.remember(gyro, accel)
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
        self.legs.add_contacts(sample.contact, sample.normal_forces)

    def _update_encoders(self, sample: EncoderSample) -> None:
        if self.state is None:
            return
        self._step(new_interval=False)      # the next interval starts from the state the feet correct
        rolling = None
        if self.params.rolling_feet:
            rolling = (self.state.feet, self._body_turn, rot.up_in_body(self.state.q), self.foot_radius)
        reading = self.legs.read(sample.positions, rolling)
        if rolling is not None:
            self._body_turn[:] = 0.0
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
        """The estimate with the nominal attitude."""
        q = self.state.q
        return self._attitude_estimate(t, *q, *rot.euler_from_quaternion(q))

    def _attitude_estimate(self, t: float, qx: float, qy: float, qz: float, qw: float, roll: float, pitch: float,
                           yaw: float) -> Estimate:
        """The estimate with this attitude (qx, qy, qz, qw, roll, pitch, yaw); its covariance, the
        bias and the terrain of the last step (they change little within a step, and are
        recomputed only there)."""
        if self._output is None:
            self._output = self._step_output(t, roll, pitch, yaw)
        return Estimate(t, np.array((qx, qy, qz, qw)), roll, pitch, yaw, *self._output)

    def _step_output(self, t: float, roll: float, pitch: float, yaw: float) -> tuple:
        terrain = self.terrain
        if terrain.x is None:
            return (*output_covariances(self.P, self.state.bias, roll, pitch, ZERO33, ZERO33, 0.0)[:3],
                    None, None, None, None)
        terrain_roll, terrain_pitch, height, covariance, growth = terrain.heading_output(yaw)
        attitude_cov, bias, bias_cov, terrain_cov = output_covariances(self.P, self.state.bias, roll, pitch, covariance,
                                                                       growth, max(0.0, t - terrain.t))
        return attitude_cov, bias, bias_cov, terrain_roll, terrain_pitch, height, terrain_cov


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
