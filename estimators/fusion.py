"""IMU + leg-kinematics fusion: the models shared by `ekf` and `ukf`, and their common front end.

Nominal state: attitude q (world_from_body), gyro bias b_g, accelerometer bias b_a, and for the
IMU point its velocity v and non-gravitational acceleration a, plus the six foot positions p_i
relative to the IMU point, all in the body frame (robocentric, so that yaw never enters).
Error state (33): dx = [dtheta (local rotation vector), db_g, dv, da, db_a, dp_1 ... dp_6]
(Sola 2017, section 5, with the accelerometer moved from the prediction to a measurement so that
the body acceleration can be modelled; foot states as in Bloesch et al. 2012, "State Estimation
for Legged Robots - Consistent Fusion of Leg Kinematics and IMU", kept in the body frame).

Process (per IMU sample, gyro w_m, w = w_m - b_g):
    q'   = q * Exp(w dt)                     gyro integration (Sola 2017, section 5.3)
    v'   = Exp(w dt)^T v + a dt              v_dot = a - w x v in a rotating frame
    a'   = exp(-dt / tau) a                  first-order Gauss-Markov body acceleration
    p_i' = Exp(w dt)^T p_i - v dt            a stance foot is fixed in the world (plus slip noise)
    b_g' = b_g, b_a' = b_a                   plus random walks
Measurements:
    specific force   f = a + g R^T e_z + b_a   the gravity direction fixes roll and pitch once a
                                              and b_a are known; its null space is yaw, which
                                              stays unobserved
    stance foot i    FK_i(encoders) - r_imu = p_i   (forward kinematics, eq. 2 of the paper)
A foot's state restarts from its kinematics at every touchdown. The feet pin the displacement of
the body, hence v and the integral of a, hence the tilt, within a fraction of a second.
A constant accelerometer bias looks like a tilt; they separate only as the body turns. By
default b_a is a "consider" state (Schmidt-Kalman): never updated, but its prior widens the tilt
covariance. Without encoders the filter falls back on the Gauss-Markov prior of a: a
gravity-direction filter whose accelerometer noise is the body acceleration.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators import rotations as rot
from estimators.base import Estimate, Estimator
from estimators.config import FusionConfig, TerrainEstimatorConfig
from estimators.leg_odometry import StanceTracker
from estimators.linalg import cross, skew
from estimators.terrain import TerrainFilter, fit_plane, slopes_and_height
from sensors.samples import EncoderSample, FootSample
from testbed.kinematics import LegGeometry

NUM_FEET = 6
ERROR_DIM = 15 + 3 * NUM_FEET
THETA, BIAS, VEL, ACC, ACCEL_BIAS = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15))
FEET = slice(15, ERROR_DIM)


VELOCITY_RANDOM_WALK = 1e-3    # m/s/sqrt(s): keeps the velocity block well conditioned


def foot(leg: int) -> slice:
    """The error-state slice of foot `leg`."""
    return slice(15 + 3 * leg, 18 + 3 * leg)


@dataclass
class NominalState:
    q: rot.Quaternion
    bias: np.ndarray          # (3,) rad/s, gyro
    velocity: np.ndarray      # (3,) m/s, IMU point, body frame
    accel: np.ndarray         # (3,) m/s^2, IMU point, body frame, gravity excluded
    accel_bias: np.ndarray    # (3,) m/s^2
    feet: np.ndarray          # (6, 3) m, from the IMU point, body frame


def propagate(state: NominalState, gyro: np.ndarray, dt: float, decay: float) -> tuple[NominalState, np.ndarray]:
    """The nominal state after dt with measured rate `gyro`; also returns Exp(w dt) as a matrix."""
    omega = gyro - state.bias
    step = rot.exp(omega[0] * dt, omega[1] * dt, omega[2] * dt)
    turn = rot.to_matrix(step)
    new = NominalState(rot.normalized(rot.multiply(state.q, step)), state.bias,
                       turn.T @ state.velocity + state.accel * dt, decay * state.accel, state.accel_bias,
                       state.feet @ turn - state.velocity * dt)    # rows: p' = turn^T p - v dt
    return new, turn


def predicted_specific_force(state: NominalState, gravity: float) -> np.ndarray:
    ux, uy, uz = rot.up_in_body(state.q)
    return state.accel + state.accel_bias + gravity * np.array([ux, uy, uz])


@dataclass(frozen=True)
class FusionNoise:
    """The FusionConfig numbers turned into variances."""
    gyro: float                 # rad^2/s
    bias_walk: float            # rad^2/s^3
    accel_density: float        # (m/s^2)^2 / Hz
    body_accel: float           # (m/s^2)^2
    accel_time_constant: float  # s
    accel_bias_walk: float      # (m/s^2)^2 / s
    foot_position: float        # m^2
    foot_slip: float            # m^2 / s

    @classmethod
    def from_config(cls, params: FusionConfig) -> "FusionNoise":
        return cls(params.gyro_noise_density**2, params.gyro_bias_random_walk**2, params.accel_noise_density**2,
                   params.body_accel_std**2, params.body_accel_time_constant, params.accel_bias_random_walk**2,
                   params.foot_position_std**2, params.foot_slip_std**2)

    def process(self, dt: float, decay: float) -> np.ndarray:
        """Diagonal of the discrete process noise over dt (Sola 2017, section 5.4.3)."""
        return np.repeat([self.gyro * dt, self.bias_walk * dt, VELOCITY_RANDOM_WALK**2 * dt,
                          self.body_accel * (1.0 - decay * decay), self.accel_bias_walk * dt]
                         + [self.foot_slip * dt] * NUM_FEET, 3)


def initial_covariance(params: FusionConfig, q: rot.Quaternion) -> np.ndarray:
    """Tilt uncertainty across the vertical, yaw uncertainty about it (both in body axes)."""
    up = np.array(rot.up_in_body(q))
    vertical = np.outer(up, up)
    tilt, yaw = math.radians(params.initial_tilt_std_deg), math.radians(params.initial_yaw_std_deg)
    covariance = np.zeros((ERROR_DIM, ERROR_DIM))
    covariance[THETA, THETA] = tilt**2 * (np.eye(3) - vertical) + yaw**2 * vertical
    covariance[BIAS, BIAS] = params.gyro_bias_initial_std**2 * np.eye(3)
    covariance[VEL, VEL] = params.initial_velocity_std**2 * np.eye(3)
    covariance[ACC, ACC] = params.body_accel_std**2 * np.eye(3)
    covariance[ACCEL_BIAS, ACCEL_BIAS] = params.accel_bias_initial_std**2 * np.eye(3)
    covariance[FEET, FEET] = params.foot_position_std**2 * np.eye(3 * NUM_FEET)    # restarted at touchdown
    return covariance


def reset_jacobian(dtheta: np.ndarray) -> np.ndarray:
    """G of the error reset after injecting dtheta into q (Sola 2017, section 6.3)."""
    jacobian = np.eye(ERROR_DIM)
    jacobian[THETA, THETA] -= 0.5 * skew(dtheta)
    return jacobian


def inject_in_place(state: NominalState, dx: np.ndarray) -> None:
    """inject, modifying `state` (the EKF's hot path)."""
    state.q = rot.rotate_by_vector(state.q, dx[0], dx[1], dx[2])
    state.bias = state.bias + dx[BIAS]
    state.velocity = state.velocity + dx[VEL]
    state.accel = state.accel + dx[ACC]
    state.accel_bias = state.accel_bias + dx[ACCEL_BIAS]
    state.feet = state.feet + dx[FEET].reshape(NUM_FEET, 3)


def inject(state: NominalState, dx: np.ndarray) -> NominalState:
    """x_true = x (+) dx (Sola 2017, section 6.2)."""
    return NominalState(rot.rotate_by_vector(state.q, dx[0], dx[1], dx[2]), state.bias + dx[BIAS],
                        state.velocity + dx[VEL], state.accel + dx[ACC], state.accel_bias + dx[ACCEL_BIAS],
                        state.feet + dx[FEET].reshape(NUM_FEET, 3))


def horizontal_basis(up: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane perpendicular to `up`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = cross(up, helper)
    first /= np.linalg.norm(first)
    return np.array([first, cross(up, first)])


class BiasStepDetector:
    """Sums the tilt corrections over a window: with a constant gyro bias they are white with the
    covariance sum of K S K^T; a chi-square excess of their horizontal part means the tilt keeps
    drifting one way, i.e. the bias changed (an innovation-based fault test, as the windowed
    NIS test of Bar-Shalom et al. 2001, section 5.4, applied to the state corrections)."""

    def __init__(self, window: float, probability: float):
        self.window = window
        self.threshold = float(chi2.ppf(probability, 2))
        self.detections = 0
        self._start: float | None = None
        self._sum = np.zeros(3)
        self._covariance = np.zeros((3, 3))

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
        self._start, self._sum, self._covariance = t, np.zeros(3), np.zeros((3, 3))
        self.detections += moved
        return moved


class FusionEstimator(Estimator):
    """Front end of `ekf` and `ukf`: time keeping, gates, leg odometry, terrain and the output.

    Subclasses hold the filter core: `state` (NominalState), `P` (33x33 error covariance) and the
    three methods below, which call `_record_tilt_correction` after every applied update.
    """

    def __init__(self, params: FusionConfig, terrain: TerrainEstimatorConfig, geometry: LegGeometry,
                 foot_radius: float, gravity: float, imu_rotation: np.ndarray | None = None,
                 imu_position: np.ndarray | None = None):
        super().__init__(imu_rotation)
        self.params = params
        self.noise = FusionNoise.from_config(params)
        self.gravity = gravity
        self.foot_radius = foot_radius
        self.imu_position = np.zeros(3) if imu_position is None else np.asarray(imu_position, dtype=float)
        self.accel_gate = float(chi2.ppf(params.accel_gate_probability, 3))
        self.foot_gate = float(chi2.ppf(params.foot_gate_probability, 3))
        self.legs = StanceTracker(geometry, params.stance_min_force)
        self.terrain = TerrainFilter(terrain)
        self.bias_steps = BiasStepDetector(params.bias_fault_window, params.bias_fault_probability)
        # States whose uncertainty is carried but which updates leave alone (Schmidt 1966).
        self.consider = None if params.accel_bias_estimation else ACCEL_BIAS
        self.state: NominalState | None = None
        self.P = np.zeros((ERROR_DIM, ERROR_DIM))
        self.t: float | None = None
        self.rejected_accel = 0
        self.tilt_restarts = 0
        self.velocity_restarts = 0
        self.rejected_feet = 0
        self._last_gyro = np.zeros(3)
        self._last_dt = 0.0
        self._accel_rejected_since: float | None = None

    # -- filter core ---------------------------------------------------------------------------

    @abc.abstractmethod
    def _predict(self, gyro: np.ndarray, dt: float) -> None:
        """Propagate state and P over dt with the mean measured rate `gyro`."""

    @abc.abstractmethod
    def _correct_specific_force(self, accel: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        """Specific-force update with noise `variance` I; applied only if the NIS <= gate.
        Returns (applied, NIS)."""

    @abc.abstractmethod
    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray, variance: float, gate: float) -> np.ndarray:
        """Update of the tracked feet `legs` with their kinematics (n, 3); a foot whose NIS exceeds
        the gate is left out. Returns the (n,) mask of the feet used."""

    def _record_tilt_correction(self, dtheta: np.ndarray, covariance: np.ndarray) -> None:
        """An applied update moved the attitude by dtheta, whose predicted covariance was `covariance`."""
        self.bias_steps.add(dtheta, covariance)

    # -- samples -------------------------------------------------------------------------------

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if self.state is None:
            return self._initialise(t, gyro, accel)
        gyro_now = self._last_gyro if gyro is None else gyro
        dt = t - self.t
        if dt > 0:
            # Trapezoidal rate over the step: second-order accurate gyro integration.
            self._predict(0.5 * (self._last_gyro + gyro_now), dt)
            self._last_dt = dt
            self.t = t
        self._last_gyro = gyro_now
        if accel is not None and self._last_dt > 0:
            self._specific_force_update(t, accel)
        if self.bias_steps.check(t, self.state.q):
            self._open_bias(np.array(rot.up_in_body(self.state.q)))
        return self._estimate(t)

    def _open_bias(self, up: np.ndarray) -> None:
        """The gyro bias moved: widen its uncertainty, and the tilt's by the drift it may have
        caused over a detection window. The tilt is widened together with the body
        acceleration, da = -g [u]x dtheta, which leaves the predicted specific force unchanged:
        otherwise the next accelerometer sample would be read as pure tilt."""
        step = self.params.bias_fault_std
        drift = step * self.bias_steps.window
        horizontal = np.eye(3) - np.outer(up, up)
        direction = np.zeros((ERROR_DIM, 3))
        direction[THETA] = horizontal
        direction[ACC] = -self.gravity * skew(up) @ horizontal
        self.P[BIAS, BIAS] += step**2 * np.eye(3)
        self.P += drift**2 * direction @ direction.T

    def _initialise(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if accel is None or not np.linalg.norm(accel) > 0:
            return None
        roll, pitch = rot.tilt_from_specific_force(*accel)
        q = rot.quaternion_from_euler(roll, pitch, 0.0)
        self.state = NominalState(q, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros((NUM_FEET, 3)))
        self.P = initial_covariance(self.params, q)
        self.t = t
        if gyro is not None:
            self._last_gyro = gyro
        return self._estimate(t)

    def _specific_force_update(self, t: float, accel: np.ndarray) -> None:
        # White-noise variance of one sample of a density: sigma^2 = density^2 / dt.
        norm = math.sqrt(accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2])
        excess = max(0.0, abs(norm - self.gravity) - self.params.accel_inflation_deadband)
        inflation = 1.0 + excess / self.params.accel_inflation_scale
        variance = self.noise.accel_density / self._last_dt * inflation**2
        applied, _ = self._correct_specific_force(accel, variance, self.accel_gate)
        if applied:
            self._accel_rejected_since = None
            return
        self.rejected_accel += 1
        if self._accel_rejected_since is None:
            self._accel_rejected_since = t
        elif t - self._accel_rejected_since > self.params.gate_recovery_time:
            # Rejected for too long: the filter, not the sensor, is off (its attitude was thrown by
            # a gyro fault, say). Restart the tilt from gravity as at start-up.
            self._accel_rejected_since = None
            self._restart_tilt(accel)

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
        self.tilt_restarts += 1

    def _update_feet(self, sample: FootSample) -> None:
        self.legs.add_contacts(sample.contact, sample.normal_forces)

    def _update_encoders(self, sample: EncoderSample) -> None:
        if self.state is None:
            return
        feet = self.legs.feet(sample.positions)
        measured = feet - self.imu_position
        measurable = self.legs.measurable(feet)
        tracked = np.flatnonzero(measurable & self.legs.tracked)
        restart = np.flatnonzero(measurable & ~self.legs.tracked)
        if len(tracked):
            used = self._correct_feet(tracked, measured[tracked], self.noise.foot_position, self.foot_gate)
            # A foot whose kinematics disagree slipped (or read badly): start it again. When most
            # of them disagree, the filter's velocity is wrong instead: reopen it too.
            self.rejected_feet += int(np.count_nonzero(~used))
            restart = np.concatenate([restart, tracked[~used]])
            if np.count_nonzero(~used) > len(used) // 2:
                self._restart_velocity()
        for leg in restart:
            self._restart_foot(leg, measured[leg])
        self._terrain_update(sample.t, feet)

    def _restart_velocity(self) -> None:
        self.P[VEL, :] = 0.0
        self.P[:, VEL] = 0.0
        self.P[VEL, VEL] = self.params.initial_velocity_std**2 * np.eye(3)
        self.velocity_restarts += 1

    def _restart_foot(self, leg: int, measured: np.ndarray) -> None:
        """A new foothold: its position is the kinematics, uncorrelated with the rest."""
        feet = self.state.feet.copy()
        feet[leg] = measured
        self.state.feet = feet
        block = foot(leg)
        self.P[block, :] = 0.0
        self.P[:, block] = 0.0
        self.P[block, block] = self.noise.foot_position * np.eye(3)
        self.legs.tracked[leg] = True

    def _terrain_update(self, t: float, feet: np.ndarray) -> None:
        stance = feet[self.legs.measurable(feet)]
        fit = fit_plane(stance @ rot.to_matrix(self.state.q).T, self.params.foot_position_std)
        if fit is not None:
            self.terrain.update(t, *slopes_and_height(fit, self.foot_radius))

    # -- output --------------------------------------------------------------------------------

    def _estimate(self, t: float) -> Estimate:
        q = self.state.q
        roll, pitch, yaw = rot.euler_from_quaternion(q)
        euler = rot.euler_jacobian(roll, pitch)
        attitude_cov = euler @ self.P[THETA, THETA] @ euler.T
        terrain = (None, None, None, None)
        if self.terrain.x is not None:
            terrain = self.terrain.output(t, yaw, attitude_cov[:2, :2])
        return Estimate(t, np.array(q), roll, pitch, yaw, attitude_cov, self.state.bias.copy(),
                        self.P[BIAS, BIAS].copy(), *terrain)
