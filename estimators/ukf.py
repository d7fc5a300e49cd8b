"""`ukf`: the models of fusion.py through filterpy's UnscentedKalmanFilter, to compare sigma points
with the EKF's linearisation on the same data.

filterpy's state `x` is the 35-dimensional error state dx = [dtheta, db_g, dv, db_a, dc, dp_1..6, dr] about
the nominal state held here. Each sigma point is injected into the nominal state (q Exp(dtheta),
...), moved over the preintegrated interval with its own biases (the increments corrected to first
order with the preintegration's bias Jacobians, Forster et al. 2017 eq. 44) or measured, and turned
back into an error about the new nominal (Log for the rotation). After every step the mean error
is injected into the nominal state and x is reset to zero (Sola 2017, section 6), so the sigma
points stay centred on it. The spread of the sigma points must stay below 180 deg about the
unobservable yaw axis: the yaw variance is capped at `max_yaw_std_deg`.

filterpy calls the process model once per sigma point (71 of them); `BatchUnscentedKalmanFilter`
only replaces that loop by the same model evaluated on all points at once (`propagate_errors`,
checked against the per-point `UkfEstimator._fx` in the tests). Everything else (sigma points,
unscented transform, gain, update) is filterpy's. The stance feet are one stacked measurement per
encoder sample, each foot first gated on its own block.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy.spatial.transform import Rotation

from testbed.model import spatial as rot
from estimators.base import imu_position, imu_rotation
from estimators.config import FusionConfig, TerrainEstimatorConfig, UkfConfig
from estimators.fusion import (ACCEL_BIAS, ACCEL_CROSS, BIAS, ERROR_DIM, FEET, NUM_FEET, POSITION, THETA, VEL,
                               FusionEstimator, NominalState, apply_preintegration, foot, foot_nis, inject,
                               reset_jacobian)
from estimators.preintegration import Preintegration
from testbed.model.kinematics import LegGeometry


def difference(state: NominalState, reference: NominalState) -> np.ndarray:
    """dx such that state = reference (+) dx."""
    dtheta = rot.log(rot.multiply(rot.conjugate(reference.q), state.q))
    return np.concatenate([dtheta, state.bias - reference.bias, state.velocity - reference.velocity,
                           state.accel_bias - reference.accel_bias, state.accel_cross - reference.accel_cross,
                           (state.feet - reference.feet).ravel(), state.position - reference.position])


def corrected(pre: Preintegration, gyro_bias_error: np.ndarray, accel_bias_error: np.ndarray) -> Preintegration:
    """The increments as if integrated with biases larger by the given errors (first order)."""
    out = pre.copy()
    out.dq[:] = rot.multiply(tuple(pre.dq), rot.exp(*(pre.j_r @ gyro_bias_error)))
    out.dv[:] = pre.dv + pre.j_v_g @ gyro_bias_error + pre.j_v_a @ accel_bias_error
    out.dp[:] = pre.dp + pre.j_p_g @ gyro_bias_error + pre.j_p_a @ accel_bias_error
    return out


def propagate_errors(sigmas: np.ndarray, before: NominalState, after: NominalState, pre: Preintegration,
                     gravity: float) -> np.ndarray:
    """fusion.apply_preintegration on every error sigma point (rows of `sigmas`) at once: inject into
    `before`, move over the interval with the point's biases, return the errors about `after`."""
    count, dt = len(sigmas), pre.dt
    gyro_error, accel_error = sigmas[:, BIAS], sigmas[:, ACCEL_BIAS]
    attitude = Rotation.from_quat(before.q) * Rotation.from_rotvec(sigmas[:, THETA])
    velocity = before.velocity + sigmas[:, VEL]
    feet = before.feet + sigmas[:, FEET].reshape(count, NUM_FEET, 3)
    step = Rotation.from_quat(pre.dq) * Rotation.from_rotvec(gyro_error @ pre.j_r.T)
    turn = step.as_matrix()
    dv = pre.dv + gyro_error @ pre.j_v_g.T + accel_error @ pre.j_v_a.T
    dp = pre.dp + gyro_error @ pre.j_p_g.T + accel_error @ pre.j_p_a.T
    attitude_matrix = attitude.as_matrix()
    up = attitude_matrix[:, 2, :]                             # third row of R: R^T e_z
    moved_velocity = np.einsum("nji,nj->ni", turn, velocity - gravity * dt * up + dv)
    feet_shift = velocity * dt - 0.5 * gravity * dt * dt * up + dp
    moved_feet = (feet - feet_shift[:, None, :]) @ turn
    moved_position = before.position + sigmas[:, POSITION] + np.einsum("nij,nj->ni", attitude_matrix,
                                                                       velocity * dt + dp)
    moved_position[:, 2] -= 0.5 * gravity * dt * dt
    out = np.empty_like(sigmas)
    out[:, THETA] = (Rotation.from_quat(after.q).inv() * attitude * step).as_rotvec()
    out[:, BIAS] = before.bias + gyro_error - after.bias
    out[:, VEL] = moved_velocity - after.velocity
    out[:, ACCEL_BIAS] = before.accel_bias + accel_error - after.accel_bias
    out[:, ACCEL_CROSS] = before.accel_cross + sigmas[:, ACCEL_CROSS] - after.accel_cross
    out[:, FEET] = (moved_feet - after.feet).reshape(count, -1)
    out[:, POSITION] = moved_position - after.position
    return out


class BatchUnscentedKalmanFilter(UnscentedKalmanFilter):
    """filterpy's UKF with the process model evaluated on all sigma points in one call."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = propagate_errors(sigmas, **fx_args)


class UkfEstimator(FusionEstimator):
    name = "ukf"

    def __init__(self, params: FusionConfig, terrain: TerrainEstimatorConfig, sigma: UkfConfig,
                 geometry: LegGeometry, foot_radius: float, gravity: float,
                 imu_rotation: np.ndarray | None = None, imu_position: np.ndarray | None = None,
                 startup_time: float = 0.0, accel_array: np.ndarray | None = None, imu_rate: float = 1000.0,
                 accel_range: float = math.inf):
        points = MerweScaledSigmaPoints(ERROR_DIM, alpha=sigma.alpha, beta=sigma.beta, kappa=sigma.kappa)
        self.ukf = BatchUnscentedKalmanFilter(dim_x=ERROR_DIM, dim_z=3, dt=1e-3, hx=self._hx_specific_force,
                                              fx=self._fx, points=points)
        self.max_yaw_variance = math.radians(sigma.max_yaw_std_deg)**2
        super().__init__(params, terrain, geometry, foot_radius, gravity, imu_rotation, imu_position, startup_time,
                         accel_array, imu_rate, accel_range)

    @classmethod
    def from_config(cls, config) -> "UkfEstimator":
        return cls(config.estimators.ekf, config.estimators.terrain, config.estimators.ukf,
                   LegGeometry.from_config(config.robot), config.robot.foot_radius, config.run.gravity,
                   imu_rotation(config), imu_position(config), config.startup_time, config.sensors.accel_array.member_positions, config.sensors.imu.rate,
                   config.sensors.imu.accel.range)

    @property
    def P(self) -> np.ndarray:
        return self.ukf.P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self.ukf.P = value

    # -- models on sigma points ----------------------------------------------------------------

    @staticmethod
    def _fx(dx: np.ndarray, dt: float, before: NominalState, after: NominalState, pre: Preintegration,
            gravity: float) -> np.ndarray:
        """The process model on one sigma point (filterpy's interface; see propagate_errors)."""
        moved, _ = apply_preintegration(inject(before, dx), corrected(pre, dx[BIAS], dx[ACCEL_BIAS]), gravity)
        return difference(moved, after)

    def _hx_specific_force(self, dx: np.ndarray) -> np.ndarray:
        """Gravity, as the z axis's cross-axis terms read it, plus offset at the sigma point."""
        ux, uy, uz = rot.up_in_body(rot.multiply(self.state.q, rot.exp(dx[0], dx[1], dx[2])))
        cx, cy = self.state.accel_cross + dx[ACCEL_CROSS]
        return self.state.accel_bias + dx[ACCEL_BIAS] + self.gravity * np.array([ux, uy, uz + cx * ux + cy * uy])

    def _hx_yaw_rate_bias(self, dx: np.ndarray) -> np.ndarray:
        return self.state.bias[2:] + dx[BIAS][2:]

    def _hx_feet(self, dx: np.ndarray, index: np.ndarray, nominal: np.ndarray) -> np.ndarray:
        return nominal + dx[index]

    # -- filter core ---------------------------------------------------------------------------

    def _predict(self) -> None:
        pre = self.pre
        before = self.state
        after, _ = apply_preintegration(before, pre, self.gravity)
        self.ukf.Q = np.diag(self.noise.process(pre.dt) + self._extra_noise())
        self.ukf.predict(dt=pre.dt, before=before, after=after, pre=pre, gravity=self.gravity)
        self.state = after
        self._reset()

    def _correct_specific_force(self, mean_force: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        return self._correct(mean_force, variance, gate, self._hx_specific_force)

    def _correct_yaw_rate_bias(self, mean_rate: float, variance: float) -> None:
        self._correct(np.array([mean_rate]), variance, math.inf, self._hx_yaw_rate_bias)

    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The feet gated one by one on their blocks (h is linear: S_i = P_ii + R), then one update."""
        variance, gate = self.noise.foot_position, self.foot_gate
        innovation = measured - self.state.feet[legs]
        blocks = [foot(leg) for leg in legs]
        accepted = np.array([foot_nis(self.P, b.start, variance, y) <= gate for y, b in zip(innovation, blocks)])
        if accepted.any():
            index = np.concatenate([np.arange(b.start, b.stop) for b, ok in zip(blocks, accepted) if ok])
            nominal = self.state.feet[legs[accepted]].ravel()
            self._correct(measured[accepted].ravel(), variance, math.inf, self._hx_feet, index=index, nominal=nominal)
        return accepted

    def _correct(self, z: np.ndarray, variance: float, gate: float, hx, **hx_args) -> tuple[bool, float]:
        prior_x, prior_P = self.ukf.x.copy(), self.ukf.P.copy()
        self.ukf.update(z, R=variance * np.eye(len(z)), hx=hx, **hx_args)
        nis = float(self.ukf.y @ self.ukf.SI @ self.ukf.y)
        if not nis <= gate:
            self.ukf.x, self.ukf.P = prior_x, prior_P
            return False, nis
        if self.consider is not None:
            # Schmidt-Kalman, as in the EKF: keep the consider states and their variance.
            c = self.consider
            self.ukf.P[c, c] += self.ukf.K[c] @ self.ukf.S @ self.ukf.K[c].T
            self.ukf.x[c] = prior_x[c]
        gain = self.ukf.K[THETA]
        self._record_tilt_correction(self.ukf.x[THETA].copy(), gain @ self.ukf.S @ gain.T)
        self._reset()
        return True, nis

    def _reset(self) -> None:
        """Inject the mean error into the nominal state, zero it, and re-centre the sigma points."""
        dx = self.ukf.x
        self.state = inject(self.state, dx)
        G = reset_jacobian(dx[THETA])
        P = G @ self.ukf.P @ G.T
        self.ukf.P = self._cap_yaw(0.5 * (P + P.T))
        self.ukf.x = np.zeros(ERROR_DIM)
        self.ukf.sigmas_f = self.ukf.points_fn.sigma_points(self.ukf.x, self.ukf.P)

    def _cap_yaw(self, P: np.ndarray) -> np.ndarray:
        """Shrink the error along the vertical (yaw) so that sigma points stay within +-180 deg."""
        direction = np.zeros(ERROR_DIM)
        direction[THETA] = rot.up_in_body(self.state.q)
        variance = direction @ P @ direction
        if variance <= self.max_yaw_variance:
            return P
        shrink = np.eye(ERROR_DIM) - (1.0 - math.sqrt(self.max_yaw_variance / variance)) * np.outer(direction, direction)
        return shrink @ P @ shrink.T
