"""`complementary`: the classic complementary filter, the simple baseline.

The gyro is integrated; at every sample the attitude is turned a fraction k = dt / (tau + dt) of
the way towards the tilt the accelerometer indicates, i.e. the gyro is trusted above
1 / (2 pi tau) Hz and the accelerometer below. The correction only tilts (it turns about
u_measured x u_estimated), so yaw is the integrated gyro. No gyro bias estimation, no gating.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.model import spatial as rot
from estimators.base import Estimate, Estimator, imu_rotation
from estimators.config import ComplementaryConfig


class ComplementaryEstimator(Estimator):
    name = "complementary"

    def __init__(self, params: ComplementaryConfig, imu_rotation: np.ndarray | None = None):
        super().__init__(imu_rotation)
        self.time_constant = params.time_constant
        self.q: rot.Quaternion | None = None
        self.t: float | None = None
        self._last_gyro = np.zeros(3)

    @classmethod
    def from_config(cls, config) -> "ComplementaryEstimator":
        return cls(config.estimators.complementary, imu_rotation(config))

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if self.q is None:
            if accel is None or not np.linalg.norm(accel) > 0:
                return None
            self.q = rot.quaternion_from_euler(*rot.tilt_from_specific_force(*accel), 0.0)
            self.t = t
            self._last_gyro = np.zeros(3) if gyro is None else gyro
            return self._estimate(t)
        gyro = self._last_gyro if gyro is None else gyro
        dt = t - self.t
        if dt <= 0:
            return None
        rate = 0.5 * (self._last_gyro + gyro)
        self.q = rot.rotate_by_vector(self.q, *(rate * dt))
        if accel is not None:
            self._tilt_towards(accel, dt / (self.time_constant + dt))
        self._last_gyro = gyro
        self.t = t
        return self._estimate(t)

    def _tilt_towards(self, accel: np.ndarray, fraction: float) -> None:
        norm = float(np.linalg.norm(accel))
        if not norm > 0:
            return
        measured = accel / norm
        estimated = np.array(rot.up_in_body(self.q))
        axis = np.cross(measured, estimated)
        sine = float(np.linalg.norm(axis))
        if sine < 1e-12:
            return
        # R Exp(d) has up vector u - d x u: d along u_m x u moves u towards u_m.
        angle = math.atan2(sine, float(measured @ estimated))
        self.q = rot.rotate_by_vector(self.q, *(fraction * angle / sine * axis))

    def _estimate(self, t: float) -> Estimate:
        roll, pitch, yaw = rot.euler_from_quaternion(self.q)
        return Estimate(t, np.array(self.q), roll, pitch, yaw)
