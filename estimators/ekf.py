"""`ekf`: error-state (multiplicative) extended Kalman filter on the fusion models of fusion.py.

Linearised error-state transition over a preintegrated interval dt (D = dR^T, U = [u_i]x, the
bias Jacobians J_* of preintegration.py; Sola 2017 section 7.2 and Forster et al. 2017 eq. 44):
    dtheta_j = D dtheta_i + J_R db_g
    dv_j     = D dv_i - g dt D U dtheta_i + (D J_v_g + [v_j]x J_R) db_g + D J_v_a db_a
    dp_j     = D (dp_i - dv_i dt + g dt^2 / 2 U dtheta_i - J_p_g db_g - J_p_a db_a) + [p_j]x J_R db_g
    dr_j     = dr_i - R_i [v_i dt + dp]x dtheta_i + R_i dt dv_i + R_i (J_p_g db_g + J_p_a db_a)
(R_i the attitude at step i, dp the preintegrated position increment; the world position r.)
The accelerometer's cross-axis terms c are constants (identity rows). A foot's kinematics give
H_p_i = I; a still window's mean specific force g u + b_a + g (c . u_xy) e_z gives H = [g [u]x, I,
g e_z u_xy^T] on (dtheta, db_a, dc). After each correction the error is injected into the nominal
state and reset (Sola 2017, section 6).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable

from testbed.model import spatial as rot
from estimators.base import imu_position, imu_rotation
from estimators.fusion import (ACCEL_BIAS, ACCEL_CROSS, BIAS, ERROR_DIM, FOOT0, POSITION0, THETA, FusionEstimator,
                               foot_nis, inject_arrays, inject_in_place)
from estimators.preintegration import current_attitude
from testbed.model.kinematics import LegGeometry

I3 = np.eye(3)
RESET_THRESHOLD = 1e-6    # rad: below it the reset changes P by under 1e-6 of itself: skipped


@njit(cache=True)
def predict(record: np.ndarray, velocity: np.ndarray, feet: np.ndarray, position: np.ndarray, P: np.ndarray,
            F: np.ndarray, noise_rates: np.ndarray, extra_noise: np.ndarray) -> rot.Quaternion:
    """Move velocity, feet, position (in place) and P over the interval preintegrated in `record`
    (a preintegration.PREINTEGRATION record); returns the attitude. The process noise is diagonal:
    `noise_rates` per second of interval plus `extra_noise`."""
    p = record[0]
    dt, gravity = p.dt, p.gravity
    q0 = (p.q0[0], p.q0[1], p.q0[2], p.q0[3])
    up = np.array(rot.up_in_body(q0))
    D = rot.to_matrix((p.dq[0], p.dq[1], p.dq[2], p.dq[3])).T
    R0 = rot.to_matrix(q0)
    body_shift = velocity * dt + p.dp
    _fill_position_transition(F, R0, body_shift, p, dt)
    position += rot.matvec3(R0, body_shift)
    position[2] -= 0.5 * gravity * dt * dt
    shift = velocity * dt - 0.5 * gravity * dt * dt * up + p.dp
    velocity[:] = rot.matvec3(D, velocity - gravity * dt * up + p.dv)
    for leg in range(feet.shape[0]):
        feet[leg] = rot.matvec3(D, feet[leg] - shift)
    _fill_transition(F, D, p, up, velocity, feet, gravity, dt)
    P[:] = F @ P @ F.T
    symmetrise(P)        # against rounding
    for i in range(P.shape[0]):
        P[i, i] += noise_rates[i] * dt + extra_noise[i]
    return current_attitude(record)


@njit(cache=True)
def _fill_position_transition(F: np.ndarray, R0: np.ndarray, body_shift: np.ndarray, p, dt: float) -> None:
    """The world position's rows of the error-state transition (module docstring), in place: R0 the
    attitude at the start of the interval, `body_shift` = v_i dt + dp (body frame)."""
    r = POSITION0
    F[r:r + 3, 0:3] = -rot.matmul3(R0, rot.skew(body_shift))
    F[r:r + 3, 3:6] = rot.matmul3(R0, p.j_p_g)
    F[r:r + 3, 6:9] = dt * R0
    F[r:r + 3, 9:12] = rot.matmul3(R0, p.j_p_a)


@njit(cache=True)
def _fill_transition(F: np.ndarray, D: np.ndarray, p, up: np.ndarray, velocity: np.ndarray,
                     feet: np.ndarray, gravity: float, dt: float) -> None:
    """The non-identity blocks of the error-state transition (module docstring), in place, with
    the bias Jacobians of the preintegration record `p`. `velocity` and `feet` are the nominal
    values after the interval."""
    DU = rot.matmul3(D, rot.skew(up))
    F[0:3, 0:3] = D
    F[0:3, 3:6] = p.j_r
    F[6:9, 0:3] = -gravity * dt * DU
    F[6:9, 3:6] = rot.matmul3(D, p.j_v_g) + rot.matmul3(rot.skew(velocity), p.j_r)
    F[6:9, 6:9] = D
    F[6:9, 9:12] = rot.matmul3(D, p.j_v_a)
    foot_theta = 0.5 * gravity * dt * dt * DU
    foot_bias = -rot.matmul3(D, p.j_p_g)
    foot_accel_bias = -rot.matmul3(D, p.j_p_a)
    for leg in range(feet.shape[0]):
        r = FOOT0 + 3 * leg
        F[r:r + 3, 0:3] = foot_theta
        F[r:r + 3, 3:6] = foot_bias + rot.matmul3(rot.skew(feet[leg]), p.j_r)
        F[r:r + 3, 6:9] = -dt * D
        F[r:r + 3, 9:12] = foot_accel_bias
        F[r:r + 3, r:r + 3] = D


@register_jitable
def kalman_correction(P: np.ndarray, PHt: np.ndarray, S_inverse: np.ndarray, innovation: np.ndarray,
                      consider_start: int, consider_stop: int) -> tuple[np.ndarray, np.ndarray]:
    """The Kalman correction of P (in place, with the reset) for an innovation of covariance S,
    P H^T = `PHt`. Returns the error dx to inject and the covariance K S K^T of its attitude part.

    The error states [consider_start, consider_stop) are Schmidt-Kalman "consider" states: they
    keep their value (zero gain) and their uncertainty. The Joseph form with that gain equals the
    optimal update plus K_c S K_c^T = (P H^T)_c S^-1 (P H^T)_c^T on their block.
    (Slices given to `@` are made contiguous: compiled, `@` on a strided view is slower.)"""
    gain = PHt @ S_inverse
    P -= gain @ PHt.T
    c0, c1 = consider_start, consider_stop
    P[c0:c1, c0:c1] += np.ascontiguousarray(PHt[c0:c1]) @ np.ascontiguousarray(gain[c0:c1].T)
    gain[c0:c1] = 0.0
    dx = gain @ innovation
    if abs(dx[0]) + abs(dx[1]) + abs(dx[2]) > RESET_THRESHOLD:
        # Reset (Sola 2017, section 6.3): P <- G P G^T, G = I - [dtheta / 2]x on the attitude block.
        G = np.eye(3) - rot.skew(0.5 * dx[0:3])
        P[0:3, :] = G @ np.ascontiguousarray(P[0:3, :])
        P[:, 0:3] = np.ascontiguousarray(P[:, 0:3]) @ G.T
    symmetrise(P)
    tilt_gain = np.ascontiguousarray(gain[0:3])
    return dx, tilt_gain @ np.ascontiguousarray(PHt[0:3].T)


# Compiled entry for the corrections made from Python (`EkfEstimator._correct`).
apply_kalman_correction = njit(cache=True)(kalman_correction)


@register_jitable
def feet_correction(P: np.ndarray, measured: np.ndarray, feet: np.ndarray, legs: np.ndarray, variance: float,
                    gate: float, consider_start: int, consider_stop: int) -> tuple:
    """The stance feet's Kalman correction: the kinematics `measured` ((n, 3), legs `legs`) of
    feet whose states are `feet` (6, 3), each gated on its own 3x3 block (NIS <= gate), then the
    accepted ones in one update of P (in place; `kalman_correction`, noise `variance` I).
    Returns (the (n,) mask of the feet used, dx, the covariance of dx's attitude part)."""
    n = legs.shape[0]
    innovation = np.empty((n, 3))
    accepted = np.empty(n, dtype=np.bool_)
    for k in range(n):
        innovation[k] = measured[k] - feet[legs[k]]
        accepted[k] = foot_nis(P, FOOT0 + 3 * legs[k], variance, innovation[k]) <= gate
    used = legs[accepted]
    if used.shape[0] == 0:
        return accepted, np.zeros(P.shape[0]), np.zeros((3, 3))
    index = np.empty(3 * used.shape[0], dtype=np.int64)
    for k in range(used.shape[0]):
        index[3 * k:3 * k + 3] = np.arange(FOOT0 + 3 * used[k], FOOT0 + 3 * used[k] + 3)
    PHt = np.ascontiguousarray(P[:, index])      # H selects the feet's states
    S = PHt[index] + variance * np.eye(index.shape[0])
    dx, tilt_cov = kalman_correction(P, PHt, np.linalg.inv(S), innovation[accepted].ravel(), consider_start,
                                     consider_stop)
    return accepted, dx, tilt_cov


# The feet update's settings, fields by name (`correct_feet`).
FEET_UPDATE = np.dtype([("variance", "f8"), ("gate", "f8"),       # m^2 per axis; NIS
                        ("consider_start", "i8"), ("consider_stop", "i8")])     # the consider block


# Compiled: the filter corrects the feet at every encoder sample.
@njit(cache=True)
def correct_feet(P: np.ndarray, measured: np.ndarray, legs: np.ndarray, settings: np.ndarray, nominal: np.ndarray,
                 q: rot.Quaternion, sums: np.ndarray) -> tuple:
    """`feet_correction` with the FEET_UPDATE record `settings`, of the nominal state whose arrays
    are the NOMINAL record `nominal` and whose attitude is q; its correction injected into that
    state (in place) and its attitude part and that part's covariance added to the TILT_SUMS
    record `sums` (BiasStepDetector.add). Returns (the mask of the feet used, the new q)."""
    u, x, s = settings[0], nominal[0], sums[0]
    accepted, dx, tilt_cov = feet_correction(P, measured, x.feet, legs, u.variance, u.gate, u.consider_start,
                                             u.consider_stop)
    if accepted.any():
        q = inject_arrays(q, dx, x)
        s.correction[:] += dx[0:3]
        s.covariance[:] += tilt_cov
    return accepted, q


@register_jitable
def symmetrise(P: np.ndarray) -> None:
    """P <- (P + P^T) / 2 in place (numba does not guard `P += P.T` against aliasing)."""
    for i in range(P.shape[0]):
        for j in range(i + 1, P.shape[0]):
            mean = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = mean
            P[j, i] = mean


def consider_bounds(consider: slice | None) -> tuple[int, int]:
    """[start, stop) of the consider block `consider` of the error state; empty without one."""
    return (0, 0) if consider is None else (consider.start, consider.stop)


class EkfEstimator(FusionEstimator):
    name = "ekf"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._F = np.eye(ERROR_DIM)
        self._noise_rates = self.noise.process(1.0)
        self._feet_update = np.zeros(1, dtype=FEET_UPDATE)
        self._feet_update[0] = self.noise.foot_position, self.foot_gate, *consider_bounds(self.consider)

    @classmethod
    def from_config(cls, config) -> "EkfEstimator":
        return cls(config.estimators.ekf, config.estimators.terrain, LegGeometry.from_config(config.robot),
                   config.robot.foot_radius, config.run.gravity, imu_rotation(config), imu_position(config),
                   config.startup_time, config.sensors.accel_array.member_positions, config.sensors.imu.rate,
                   config.sensors.imu.accel.range)

    def _predict(self) -> None:
        state = self.state
        state.q = predict(self.pre.record, state.velocity, state.feet, state.position, self.P, self._F,
                          self._noise_rates, self._extra_noise())

    def _correct_specific_force(self, mean_force: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        ux, uy, uz = rot.up_in_body(self.state.q)
        g = self.gravity
        H = np.zeros((3, ERROR_DIM))
        H[:, THETA] = rot.skew((g * ux, g * uy, g * uz))
        H[:, ACCEL_BIAS] = I3
        H[2, ACCEL_CROSS] = g * ux, g * uy
        cx, cy = self.state.accel_cross
        predicted = self.state.accel_bias + (g * ux, g * uy, g * (uz + cx * ux + cy * uy))
        return self._correct(H, mean_force - predicted, variance, gate)

    def _correct_yaw_rate_bias(self, mean_rate: float, variance: float) -> None:
        H = np.zeros((1, ERROR_DIM))
        H[0, BIAS.start + 2] = 1.0
        self._correct(H, np.array([mean_rate - self.state.bias[2]]), variance, math.inf)

    def _hold_accel_bias(self) -> None:
        super()._hold_accel_bias()
        self._feet_update[0]["consider_start"], self._feet_update[0]["consider_stop"] = consider_bounds(self.consider)

    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray) -> np.ndarray:
        state = self.state
        accepted, state.q = correct_feet(self.P, measured, legs, self._feet_update, self.nominal, state.q,
                                         self.bias_steps.sums)
        return accepted

    def _correct(self, H: np.ndarray, innovation: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        """Gated Kalman update, noise `variance` I. Returns (applied, NIS)."""
        PHt = self.P @ H.T
        S = H @ PHt
        S.flat[::len(S) + 1] += variance
        S_inverse = np.linalg.inv(S)
        nis = float(innovation @ S_inverse @ innovation)
        if not nis <= gate:
            return False, nis
        dx, tilt_cov = apply_kalman_correction(self.P, PHt, S_inverse, innovation,
                                                *consider_bounds(self.consider))
        self._inject(dx, tilt_cov)
        return True, nis

    def _inject(self, dx: np.ndarray, tilt_cov: np.ndarray) -> None:
        """Inject a correction dx into the nominal state, and record its attitude part."""
        inject_in_place(self.state, self.nominal, dx)
        self._record_tilt_correction(dx[THETA], tilt_cov)
