"""`ekf`: error-state (multiplicative) extended Kalman filter on the fusion models of fusion.py.

Linearised error-state transition over dt (Sola 2017, sections 5.3.3 and 5.4.3, with the
accelerometer as a measurement; T = Exp(w dt)):
    dtheta' = T^T dtheta - db_g dt
    dv'     = T^T dv - [v]x db_g dt + da dt
    da'     = exp(-dt / tau) da
    dp_i'   = T^T dp_i - [p_i]x db_g dt - dv dt
Measurement Jacobians: the specific force f = a + g R^T e_z + b_a gives H_theta = g [R^T e_z]x,
H_a = H_ba = I (after R Exp(dtheta), R^T e_z = u + u x dtheta); a foot's kinematics give
H_p_i = I. After each correction the error is injected into the nominal state and reset
(Sola 2017, section 6).
"""

from __future__ import annotations

import math

import numpy as np

from estimators import rotations as rot
from estimators.base import imu_position, imu_rotation
from estimators.fusion import (ACC, ACCEL_BIAS, BIAS, ERROR_DIM, FEET, NUM_FEET, THETA, VEL, FusionEstimator, foot,
                               inject_in_place, predicted_specific_force, propagate)
from estimators.linalg import inverse3, skew, stacked_skew
from testbed.config import Config
from testbed.kinematics import LegGeometry

I3 = np.eye(3)
RESET_THRESHOLD = 1e-6    # rad: below it the reset changes P by under 1e-6 of itself: skipped
# Index arrays that fill the feet's diagonal blocks of F in one assignment.
_FOOT_BLOCK_ROWS, _FOOT_BLOCK_COLUMNS = np.nonzero(np.kron(np.eye(NUM_FEET), np.ones((3, 3))))
_FOOT_BLOCK_ROWS, _FOOT_BLOCK_COLUMNS = _FOOT_BLOCK_ROWS + FEET.start, _FOOT_BLOCK_COLUMNS + FEET.start


class EkfEstimator(FusionEstimator):
    name = "ekf"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._F = np.eye(ERROR_DIM)
        self._F_dt: float | None = None
        self._process_diagonal = np.zeros(ERROR_DIM)
        self._foot_blocks = np.zeros((NUM_FEET, 9))
        self._H_specific_force = np.zeros((3, ERROR_DIM))     # H_a = H_ba = I; H_theta set per sample
        self._H_specific_force[:, ACC] = I3
        self._H_specific_force[:, ACCEL_BIAS] = I3

    @classmethod
    def from_config(cls, config: Config) -> "EkfEstimator":
        return cls(config.estimators.ekf, config.estimators.terrain, LegGeometry.from_config(config.robot),
                   config.robot.foot_radius, config.run.gravity, imu_rotation(config), imu_position(config))

    def _predict(self, gyro: np.ndarray, dt: float) -> None:
        old = self.state
        if self._F_dt is None or abs(dt - self._F_dt) > 1e-9 * dt:
            self._set_step(dt)
        self.state, turn = propagate(old, gyro, dt, self._decay)
        F = self._F
        F[THETA, THETA] = turn.T
        F[VEL, BIAS] = skew(-dt * old.velocity)
        F[VEL, VEL] = turn.T
        self._foot_blocks[:] = turn.T.ravel()
        F[_FOOT_BLOCK_ROWS, _FOOT_BLOCK_COLUMNS] = self._foot_blocks.ravel()
        F[FEET, BIAS] = stacked_skew(-dt * old.feet)
        P = F @ self.P @ F.T
        P += P.T        # F P F^T + Q, symmetrised against rounding
        P *= 0.5
        P.flat[::ERROR_DIM + 1] += self._process_diagonal
        self.P = P

    def _set_step(self, dt: float) -> None:
        """The parts of F and Q that depend on dt only (the IMU rate is usually constant)."""
        self._F_dt = dt
        self._decay = math.exp(-dt / self.noise.accel_time_constant)
        self._F[THETA, BIAS] = -dt * I3
        self._F[VEL, ACC] = dt * I3
        self._F[ACC, ACC] = self._decay * I3
        self._F[FEET, VEL] = np.tile(-dt * I3, (NUM_FEET, 1))
        self._process_diagonal = self.noise.process(dt, self._decay)

    def _correct_specific_force(self, accel: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        ux, uy, uz = rot.up_in_body(self.state.q)
        H = self._H_specific_force
        H[:, THETA] = skew((self.gravity * ux, self.gravity * uy, self.gravity * uz))
        return self._correct(H, accel - predicted_specific_force(self.state, self.gravity), variance, gate)

    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray, variance: float, gate: float) -> np.ndarray:
        """All stance feet at once; each foot is gated on its own 3x3 innovation block first."""
        innovation = measured - self.state.feet[legs]
        blocks = [foot(leg) for leg in legs]
        nis = np.array([y @ inverse3(self.P[b, b] + variance * I3) @ y for y, b in zip(innovation, blocks)])
        accepted = nis <= gate
        if accepted.any():
            index = np.concatenate([np.arange(b.start, b.stop) for b, ok in zip(blocks, accepted) if ok])
            PHt = self.P[:, index]
            S = PHt[index]
            S.flat[::len(index) + 1] += variance
            self._apply(PHt, np.linalg.inv(S), innovation[accepted].ravel())
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
        self.P = P      # symmetrised once per IMU sample, in _predict
        inject_in_place(self.state, dx)
        self._record_tilt_correction(dtheta, gain[THETA] @ PHt[THETA].T)
