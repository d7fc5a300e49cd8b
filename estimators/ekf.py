"""`ekf`: error-state (multiplicative) extended Kalman filter on the fusion models of fusion.py.

Linearised error-state transition over a preintegrated interval dt (D = dR^T, U = [u_i]x, the
bias Jacobians J_* of preintegration.py; Sola 2017 section 7.2 and Forster et al. 2017 eq. 44):
    dtheta_j = D dtheta_i + J_R db_g
    dv_j     = D dv_i - g dt D U dtheta_i + (D J_v_g + [v_j]x J_R) db_g + D J_v_a db_a
    dp_j     = D (dp_i - dv_i dt + g dt^2 / 2 U dtheta_i - J_p_g db_g - J_p_a db_a) + [p_j]x J_R db_g
The accelerometer's cross-axis terms c are constants (identity rows). A foot's kinematics give
H_p_i = I; a still window's mean specific force g u + b_a + g (c . u_xy) e_z gives H = [g [u]x, I,
g e_z u_xy^T] on (dtheta, db_a, dc). After each correction the error is injected into the nominal
state and reset (Sola 2017, section 6).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.model import spatial as rot
from estimators.base import imu_position, imu_rotation
from estimators.fusion import (ACCEL_BIAS, ACCEL_CROSS, ERROR_DIM, FOOT0, THETA, FusionEstimator, inject_arrays,
                               inject_in_place)
from estimators.linalg import inverse3, product3, skew, transposed_product3
from estimators.preintegration import (DP, DT, DV, J_P_A, J_P_G, J_R, J_V_A, J_V_G, JACOBIANS,
                                       current_attitude, quaternion_matrix, skew3)
from testbed.model.kinematics import LegGeometry

I3 = np.eye(3)
RESET_THRESHOLD = 1e-6    # rad: below it the reset changes P by under 1e-6 of itself: skipped


@njit(cache=True)
def predict(buffer: np.ndarray, velocity: np.ndarray, feet: np.ndarray, P: np.ndarray, F: np.ndarray,
            noise_rates: np.ndarray, extra_noise: np.ndarray, gravity: float) -> tuple[float, float, float, float]:
    """Move velocity, feet (in place) and P over the preintegrated interval; returns the attitude.
    The process noise is diagonal: `noise_rates` per second of interval plus `extra_noise`."""
    dt = buffer[DT]
    qx, qy, qz, qw = buffer[0], buffer[1], buffer[2], buffer[3]
    up = np.array([2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)])
    D = quaternion_matrix(buffer[16], buffer[17], buffer[18], buffer[19]).T
    shift = velocity * dt - 0.5 * gravity * dt * dt * up + buffer[DP]
    velocity[:] = transposed_product3(D, velocity - gravity * dt * up + buffer[DV])
    for leg in range(feet.shape[0]):
        feet[leg] = transposed_product3(D, feet[leg] - shift)
    _fill_transition(F, D, buffer[JACOBIANS].reshape(5, 3, 3), up, velocity, feet, gravity, dt)
    P[:] = F @ P @ F.T
    _symmetrise(P)        # against rounding
    for i in range(P.shape[0]):
        P[i, i] += noise_rates[i] * dt + extra_noise[i]
    return current_attitude(buffer)


@njit(cache=True)
def _fill_transition(F: np.ndarray, D: np.ndarray, J: np.ndarray, up: np.ndarray, velocity: np.ndarray,
                     feet: np.ndarray, gravity: float, dt: float) -> None:
    """The non-identity blocks of the error-state transition (module docstring), in place.
    `velocity` and `feet` are the nominal values after the interval."""
    DU = product3(D, skew3(up[0], up[1], up[2]))
    JR = J[J_R]
    F[0:3, 0:3] = D
    F[0:3, 3:6] = JR
    F[6:9, 0:3] = -gravity * dt * DU
    F[6:9, 3:6] = product3(D, J[J_V_G]) + product3(skew3(velocity[0], velocity[1], velocity[2]), JR)
    F[6:9, 6:9] = D
    F[6:9, 9:12] = product3(D, J[J_V_A])
    foot_theta = 0.5 * gravity * dt * dt * DU
    foot_bias = -product3(D, J[J_P_G])
    foot_accel_bias = -product3(D, J[J_P_A])
    for leg in range(feet.shape[0]):
        r = FOOT0 + 3 * leg
        F[r:r + 3, 0:3] = foot_theta
        F[r:r + 3, 3:6] = foot_bias + product3(skew3(feet[leg, 0], feet[leg, 1], feet[leg, 2]), JR)
        F[r:r + 3, 6:9] = -dt * D
        F[r:r + 3, 9:12] = foot_accel_bias
        F[r:r + 3, r:r + 3] = D


@njit(cache=True)
def update_feet(P: np.ndarray, innovation: np.ndarray, legs: np.ndarray, variance: float, gate: float,
                consider: bool, dx: np.ndarray, tilt_cov: np.ndarray) -> np.ndarray:
    """Kalman update of P (in place) with the stance feet `legs` (their kinematics minus their
    states: `innovation`, (n, 3)); each foot is first gated on its own 3x3 block. Writes the
    correction dx (30,) and the covariance of its attitude part; returns the mask of feet used.
    With `consider`, the accelerometer offset is a Schmidt-Kalman consider state: zero gain, and
    the Joseph form with that gain = the optimal update plus K_c S K_c^T on its block."""
    n = legs.shape[0]
    accepted = np.zeros(n, dtype=np.bool_)
    count = 0
    for k in range(n):
        accepted[k] = _foot_nis(P, FOOT0 + 3 * legs[k], variance, innovation[k]) <= gate
        count += accepted[k]
    dx[:] = 0.0
    tilt_cov[:] = 0.0
    if count == 0:
        return accepted
    index = np.empty(3 * count, dtype=np.int64)
    z = np.empty(3 * count)
    m = 0
    for k in range(n):
        if accepted[k]:
            for i in range(3):
                index[m] = FOOT0 + 3 * legs[k] + i
                z[m] = innovation[k, i]
                m += 1
    PHt = np.ascontiguousarray(P[:, index])
    S = np.ascontiguousarray(PHt[index, :])
    for i in range(m):
        S[i, i] += variance
    gain = PHt @ np.linalg.inv(S)
    P -= gain @ PHt.T
    if consider:
        P[9:FOOT0, 9:FOOT0] += PHt[9:FOOT0] @ gain[9:FOOT0].T
        gain[9:FOOT0] = 0.0
    dx[:] = gain @ z
    tilt_cov[:] = gain[0:3] @ PHt[0:3].T
    if abs(dx[0]) + abs(dx[1]) + abs(dx[2]) > RESET_THRESHOLD:
        # Reset (Sola 2017, section 6.3): P <- G P G^T, G = I - [dtheta / 2]x on the attitude block.
        G = np.eye(3) - skew3(0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2])
        P[0:3, :] = G @ P[0:3, :]
        P[:, 0:3] = P[:, 0:3] @ G.T
    _symmetrise(P)
    return accepted


@njit(cache=True)
def correct_feet(P: np.ndarray, measured: np.ndarray, legs: np.ndarray, variance: float, gate: float, consider: bool,
                 dx: np.ndarray, tilt_cov: np.ndarray, q: rot.Quaternion, bias: np.ndarray, velocity: np.ndarray,
                 accel_bias: np.ndarray, accel_cross: np.ndarray, feet: np.ndarray, tilt_sum: np.ndarray,
                 tilt_cov_sum: np.ndarray) -> tuple:
    """`update_feet` with the feet's kinematics `measured` ((n, 3), legs `legs`), then the
    correction injected into the nominal state (its arrays in place) and its tilt part and that
    part's covariance added to `tilt_sum` and `tilt_cov_sum` (BiasStepDetector.add, in place).
    Returns (accepted, new q, whether any foot was)."""
    accepted = update_feet(P, measured - feet[legs], legs, variance, gate, consider, dx, tilt_cov)
    applied = accepted.any()
    if applied:
        q = inject_arrays(q, dx, bias, velocity, accel_bias, accel_cross, feet)
        tilt_sum += dx[0:3]
        tilt_cov_sum += tilt_cov
    return accepted, q, applied


@njit(cache=True)
def _foot_nis(P: np.ndarray, b: int, variance: float, y: np.ndarray) -> float:
    """y^T S^-1 y, S = P[b:b+3, b:b+3] + variance I, through the Cholesky factor of S in closed
    form: a LAPACK solve per foot cost more than the whole gate (S is symmetric positive definite;
    the NIS agrees with np.linalg.solve's to a few ulps, and only decides the gate)."""
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


@njit(cache=True)
def _symmetrise(P: np.ndarray) -> None:
    """P <- (P + P^T) / 2 in place (numba does not guard `P += P.T` against aliasing)."""
    for i in range(P.shape[0]):
        for j in range(i + 1, P.shape[0]):
            mean = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = mean
            P[j, i] = mean


class EkfEstimator(FusionEstimator):
    name = "ekf"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._F = np.eye(ERROR_DIM)
        self._noise_rates = self.noise.process(1.0)
        self._dx = np.zeros(ERROR_DIM)
        self._tilt_cov = np.zeros((3, 3))

    @classmethod
    def from_config(cls, config) -> "EkfEstimator":
        return cls(config.estimators.ekf, config.estimators.terrain, LegGeometry.from_config(config.robot),
                   config.robot.foot_radius, config.run.gravity, imu_rotation(config), imu_position(config),
                   config.gait.startup_time)

    def _predict(self) -> None:
        state = self.state
        state.q = predict(self.pre.buffer, state.velocity, state.feet, self.P, self._F, self._noise_rates,
                          self._extra_noise(), self.gravity)

    def _correct_specific_force(self, mean_force: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        ux, uy, uz = rot.up_in_body(self.state.q)
        g = self.gravity
        H = np.zeros((3, ERROR_DIM))
        H[:, THETA] = skew((g * ux, g * uy, g * uz))
        H[:, ACCEL_BIAS] = I3
        H[2, ACCEL_CROSS] = g * ux, g * uy
        cx, cy = self.state.accel_cross
        predicted = self.state.accel_bias + (g * ux, g * uy, g * (uz + cx * ux + cy * uy))
        return self._correct(H, mean_force - predicted, variance, gate)

    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray, variance: float, gate: float) -> np.ndarray:
        state, dx, tilt_cov = self.state, self._dx, self._tilt_cov
        # The tilt correction is recorded (_record_tilt_correction) inside the kernel.
        accepted, q, applied = correct_feet(self.P, measured, legs, variance, gate, self.consider is not None, dx,
                                            tilt_cov, state.q, state.bias, state.velocity, state.accel_bias,
                                            state.accel_cross, state.feet, *self.bias_steps.sums)
        if applied:
            state.q = q
        return accepted

    def _correct(self, H: np.ndarray, innovation: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        """Gated Kalman update for a 3-vector measurement. Returns (applied, NIS)."""
        PHt = self.P @ H.T
        S = H @ PHt
        S.flat[::4] += variance
        S_inverse = inverse3(S)
        nis = float(innovation @ S_inverse @ innovation)
        if not nis <= gate:
            return False, nis
        self._apply(PHt, S_inverse, innovation)
        return True, nis

    def _apply(self, PHt: np.ndarray, S_inverse: np.ndarray, innovation: np.ndarray) -> None:
        """Kalman correction, error injection and reset."""
        gain = PHt @ S_inverse
        P = self.P - gain @ PHt.T
        if self.consider is not None:
            # Schmidt-Kalman: "consider" states keep their value (zero gain) and their uncertainty.
            # The Joseph form with that gain equals the optimal update plus K_c S K_c^T on their block.
            c = self.consider
            P[c, c] += PHt[c] @ gain[c].T       # K_c S K_c^T = (P H^T)_c S^-1 (P H^T)_c^T
            gain[c] = 0.0
        dx = gain @ innovation
        dtheta = dx[THETA]
        if abs(dtheta[0]) + abs(dtheta[1]) + abs(dtheta[2]) > RESET_THRESHOLD:
            # Reset (Sola 2017, section 6.3): P <- G P G^T, G = I - [dtheta / 2]x on the attitude block.
            G = I3 - skew(0.5 * dtheta)
            P[THETA, :] = G @ P[THETA, :]
            P[:, THETA] = P[:, THETA] @ G.T
        P += P.T
        P *= 0.5
        self.P = P
        inject_in_place(self.state, dx)
        self._record_tilt_correction(dtheta, gain[THETA] @ PHt[THETA].T)
