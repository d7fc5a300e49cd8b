"""`ukf`: the models of fusion.py through filterpy's UnscentedKalmanFilter, to compare sigma points
with the EKF's linearisation on the same data.

filterpy's state `x` is the 33-dimensional error state dx = [dtheta, db_g, dv, da, db_a, dp_1..6] about the
nominal state held here. Each sigma point is injected into the nominal state (q Exp(dtheta), ...),
propagated or measured with the nonlinear models, and turned back into an error about the new
nominal (Log for the rotation). After every step the mean error is injected into the nominal
state and x is reset to zero (Sola 2017, section 6), so the sigma points stay centred on it.
The spread of the sigma points must stay below 180 deg about the unobservable yaw axis: the yaw
variance is capped at `max_yaw_std_deg`.

filterpy calls the process model once per sigma point (67 of them); `BatchUnscentedKalmanFilter`
only replaces that loop by the same model evaluated on all points at once (`propagate_errors`,
checked against the per-point `UkfEstimator._fx` in the tests). Everything else (sigma points,
unscented transform, gain, update) is filterpy's.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from estimators import rotations as rot
from estimators.base import imu_position, imu_rotation
from estimators.config import FusionConfig, TerrainEstimatorConfig, UkfConfig
from estimators.fusion import (ACC, ACCEL_BIAS, BIAS, ERROR_DIM, FEET, NUM_FEET, THETA, VEL, FusionEstimator,
                               NominalState, inject, propagate, reset_jacobian)
from testbed.config import Config
from testbed.kinematics import LegGeometry


def difference(state: NominalState, reference: NominalState) -> np.ndarray:
    """dx such that state = reference (+) dx."""
    dtheta = rot.log(rot.multiply(rot.conjugate(reference.q), state.q))
    return np.concatenate([dtheta, state.bias - reference.bias, state.velocity - reference.velocity,
                           state.accel - reference.accel, state.accel_bias - reference.accel_bias,
                           (state.feet - reference.feet).ravel()])


def propagate_errors(sigmas: np.ndarray, dt: float, before: NominalState, after: NominalState,
                     gyro: np.ndarray, decay: float) -> np.ndarray:
    """fusion.propagate on every error sigma point (rows of `sigmas`) at once: inject into
    `before`, propagate, and return the errors about `after`."""
    count = len(sigmas)
    q = rot.multiply_batch(np.array(before.q), rot.exp_batch(sigmas[:, THETA]))
    bias = before.bias + sigmas[:, BIAS]
    velocity = before.velocity + sigmas[:, VEL]
    accel = before.accel + sigmas[:, ACC]
    feet = before.feet + sigmas[:, FEET].reshape(count, NUM_FEET, 3)
    step = rot.exp_batch((gyro - bias) * dt)
    turn = rot.to_matrix_batch(step)
    moved_q = rot.normalized_batch(rot.multiply_batch(q, step))
    moved_velocity = np.einsum("nji,nj->ni", turn, velocity) + accel * dt
    moved_feet = feet @ turn - velocity[:, None, :] * dt
    out = np.empty_like(sigmas)
    out[:, THETA] = rot.log_batch(rot.multiply_batch(np.array(rot.conjugate(after.q)), moved_q))
    out[:, BIAS] = bias - after.bias
    out[:, VEL] = moved_velocity - after.velocity
    out[:, ACC] = decay * accel - after.accel
    out[:, ACCEL_BIAS] = before.accel_bias + sigmas[:, ACCEL_BIAS] - after.accel_bias
    out[:, FEET] = (moved_feet - after.feet).reshape(count, -1)
    return out


class BatchUnscentedKalmanFilter(UnscentedKalmanFilter):
    """filterpy's UKF with the process model evaluated on all sigma points in one call."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = propagate_errors(sigmas, dt, **fx_args)


class UkfEstimator(FusionEstimator):
    name = "ukf"

    def __init__(self, params: FusionConfig, terrain: TerrainEstimatorConfig, sigma: UkfConfig,
                 geometry: LegGeometry, foot_radius: float, gravity: float,
                 imu_rotation: np.ndarray | None = None, imu_position: np.ndarray | None = None):
        points = MerweScaledSigmaPoints(ERROR_DIM, alpha=sigma.alpha, beta=sigma.beta, kappa=sigma.kappa)
        self.ukf = BatchUnscentedKalmanFilter(dim_x=ERROR_DIM, dim_z=3, dt=1e-3, hx=self._hx_specific_force,
                                              fx=self._fx, points=points)
        self.max_yaw_variance = math.radians(sigma.max_yaw_std_deg)**2
        super().__init__(params, terrain, geometry, foot_radius, gravity, imu_rotation, imu_position)

    @classmethod
    def from_config(cls, config: Config) -> "UkfEstimator":
        return cls(config.estimators.ekf, config.estimators.terrain, config.estimators.ukf,
                   LegGeometry.from_config(config.robot), config.robot.foot_radius, config.run.gravity,
                   imu_rotation(config), imu_position(config))

    @property
    def P(self) -> np.ndarray:
        return self.ukf.P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self.ukf.P = value

    # -- models on sigma points ----------------------------------------------------------------

    @staticmethod
    def _fx(dx: np.ndarray, dt: float, before: NominalState, after: NominalState, gyro: np.ndarray,
            decay: float) -> np.ndarray:
        """The process model on one sigma point (filterpy's interface; see propagate_errors)."""
        moved, _ = propagate(inject(before, dx), gyro, dt, decay)
        return difference(moved, after)

    def _hx_specific_force(self, dx: np.ndarray) -> np.ndarray:
        """fusion.predicted_specific_force of the sigma point, without building its whole state."""
        ux, uy, uz = rot.up_in_body(rot.multiply(self.state.q, rot.exp(dx[0], dx[1], dx[2])))
        return (self.state.accel + dx[ACC] + self.state.accel_bias + dx[ACCEL_BIAS]
                + self.gravity * np.array([ux, uy, uz]))

    def _hx_foot(self, dx: np.ndarray, leg: int) -> np.ndarray:
        return self.state.feet[leg] + dx[FEET][3 * leg:3 * leg + 3]

    # -- filter core ---------------------------------------------------------------------------

    def _predict(self, gyro: np.ndarray, dt: float) -> None:
        decay = math.exp(-dt / self.noise.accel_time_constant)
        after, _ = propagate(self.state, gyro, dt, decay)
        self.ukf.Q = np.diag(self.noise.process(dt, decay))
        self.ukf.predict(dt=dt, before=self.state, after=after, gyro=gyro, decay=decay)
        self.state = after
        self._reset()

    def _correct_specific_force(self, accel: np.ndarray, variance: float, gate: float) -> tuple[bool, float]:
        return self._correct(accel, variance, gate, self._hx_specific_force)

    def _correct_feet(self, legs: np.ndarray, measured: np.ndarray, variance: float, gate: float) -> np.ndarray:
        """One foot after the other (sigma points are redrawn in between)."""
        return np.array([self._correct(z, variance, gate, self._hx_foot, leg=leg)[0] for leg, z in zip(legs, measured)])

    def _correct(self, z: np.ndarray, variance: float, gate: float, hx, **hx_args) -> tuple[bool, float]:
        prior_x, prior_P = self.ukf.x.copy(), self.ukf.P.copy()
        self.ukf.update(z, R=variance * np.eye(3), hx=hx, **hx_args)
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
