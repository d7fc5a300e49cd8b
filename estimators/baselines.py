"""Independent baselines wrapped from libraries: Madgwick and Mahony from `ahrs`, VQF from `vqf`.

Conventions checked against ours (tests/estimators/test_baselines.py):
- both libraries return quaternions scalar first (w, x, y, z); ours are scalar last;
- in IMU mode both use a z-up reference: the accelerometer at rest reads +g along the world's up
  axis, and the quaternion rotates sensor vectors into that frame (world_from_body), so roll and
  pitch match ours (NED only enters ahrs' magnetometer modes, unused here);
- ahrs' `updateIMU` returns the attitude unchanged, skipping the accelerometer correction, when the
  gyro reads exactly zero: the wrappers pass 1e-12 rad/s instead, which changes nothing else;
- VQF ignores an all-zero accelerometer sample and needs its sampling time when constructed: the
  wrapper builds it at the second IMU sample from the first interval;
- units are rad/s and m/s^2 for both.
All three are fed body-frame samples (the IMU mounting rotation is applied by the base class).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from ahrs.filters import Madgwick, Mahony
from vqf import VQF

from estimators.base import Estimate, Estimator, imu_rotation, stacked_readings
from estimators.config import MadgwickConfig, MahonyConfig, VqfConfig
from sensors.samples import ImuSample, Sample
from testbed.model import spatial as rot

TINY_RATE = np.array([1e-12, 0.0, 0.0])    # rad/s, stands in for an exactly-zero gyro reading
NO_ACCEL = np.zeros(3)                     # m/s^2, VQF skips all-zero accelerometer samples
IDENTITY = np.eye(3)


def scalar_last(q_wxyz: np.ndarray) -> rot.Quaternion:
    w, x, y, z = np.asarray(q_wxyz, dtype=float).tolist()
    return rot.normalized((x, y, z, w))


def scalar_first(q: rot.Quaternion) -> np.ndarray:
    return np.array([q[3], q[0], q[1], q[2]])


def initial_quaternion(accel: np.ndarray) -> rot.Quaternion:
    """Same start for every estimator: tilt from the first accelerometer sample, yaw zero."""
    return rot.quaternion_from_euler(*rot.tilt_from_specific_force(*accel), 0.0)


def attitude_estimate(t: float, q: rot.Quaternion, gyro_bias: np.ndarray | None = None,
                      gyro_bias_cov: np.ndarray | None = None) -> Estimate:
    roll, pitch, yaw = rot.euler_from_quaternion(q)
    return Estimate(t, np.array(q), roll, pitch, yaw, gyro_bias=gyro_bias, gyro_bias_cov=gyro_bias_cov)


class _AhrsEstimator(Estimator):
    """Shared stepping of ahrs' per-sample `updateIMU(q, gyr, acc, dt)`."""
    sample_types = (ImuSample,)

    def __init__(self, filter_, imu_rotation: np.ndarray | None = None):
        super().__init__(imu_rotation)
        self.filter = filter_
        self.q_wxyz: np.ndarray | None = None
        self.t: float | None = None

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if self.q_wxyz is None:
            if accel is None or not np.linalg.norm(accel) > 0:
                return None
            self.q_wxyz = scalar_first(initial_quaternion(accel))
            self.t = t
            return self._estimate(t)
        dt = t - self.t
        if gyro is None or dt <= 0:
            return None
        gyro = gyro if gyro.any() else TINY_RATE
        accel = np.zeros(3) if accel is None else accel    # ahrs: zero norm means gyro only
        self.q_wxyz = self.filter.updateIMU(self.q_wxyz, gyr=gyro, acc=accel, dt=dt)
        self.t = t
        return self._estimate(t)

    def _estimate(self, t: float) -> Estimate:
        return attitude_estimate(t, scalar_last(self.q_wxyz))


class MadgwickEstimator(_AhrsEstimator):
    name = "madgwick"

    def __init__(self, params: MadgwickConfig, imu_rotation: np.ndarray | None = None):
        super().__init__(Madgwick(gain=params.gain), imu_rotation)

    @classmethod
    def from_config(cls, config) -> "MadgwickEstimator":
        return cls(config.estimators.madgwick, imu_rotation(config))


class MahonyEstimator(_AhrsEstimator):
    name = "mahony"

    def __init__(self, params: MahonyConfig, imu_rotation: np.ndarray | None = None):
        super().__init__(Mahony(k_P=params.k_p, k_I=params.k_i), imu_rotation)

    @classmethod
    def from_config(cls, config) -> "MahonyEstimator":
        return cls(config.estimators.mahony, imu_rotation(config))

    def _estimate(self, t: float) -> Estimate:
        # Mahony integrates its bias estimate b and uses gyr - b.
        return attitude_estimate(t, scalar_last(self.q_wxyz), gyro_bias=np.array(self.filter.b, dtype=float))


class VqfEstimator(Estimator):
    name = "vqf"
    sample_types = (ImuSample,)

    def __init__(self, params: VqfConfig, imu_rotation: np.ndarray | None = None):
        super().__init__(imu_rotation)
        self.params = params
        self.filter: VQF | None = None
        self._first: tuple[float, np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_config(cls, config) -> "VqfEstimator":
        return cls(config.estimators.vqf, imu_rotation(config))

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        if gyro is None:
            return None
        accel = NO_ACCEL if accel is None else accel
        if self.filter is None:
            if self._first is None or t <= self._first[0]:
                self._first = (t, gyro, accel)
                return None
            self.filter = VQF(t - self._first[0], tauAcc=self.params.tau_acc,
                              motionBiasEstEnabled=self.params.motion_bias_estimation,
                              restBiasEstEnabled=self.params.rest_bias_estimation,
                              biasSigmaInit=self.params.bias_sigma_init_deg, biasClip=self.params.bias_clip_deg)
            self.filter.update(np.ascontiguousarray(self._first[1]), np.ascontiguousarray(self._first[2]))
        self.filter.update(np.ascontiguousarray(gyro), np.ascontiguousarray(accel))
        bias, sigma = self.filter.getBiasEstimate()
        return self._estimate(t, self.filter.getQuat6D(), np.array(bias, dtype=float), sigma)

    @staticmethod
    def _estimate(t: float, q_wxyz: np.ndarray, bias: np.ndarray, bias_sigma: float) -> Estimate:
        return attitude_estimate(t, scalar_last(q_wxyz), bias, bias_sigma**2 * IDENTITY)

    def update_batch(self, samples: Iterable[Sample]) -> list[Estimate]:
        """`update` sample by sample until the filter exists, then VQF's compiled `updateBatch`
        over the remaining IMU samples (the same per-sample update, looped in C++)."""
        samples = samples if isinstance(samples, Sequence) else list(samples)
        estimates, start = [], 0
        while self.filter is None and start < len(samples):
            estimate = self.update(samples[start])
            start += 1
            if estimate is not None:
                estimates.append(estimate)
        if self.filter is None:         # too few samples to build it
            return estimates
        readings = self._batch_readings([s for s in samples[start:] if isinstance(s, ImuSample)])
        if readings is None:
            return estimates + super().update_batch(samples[start:])
        t, gyro, accel = readings
        out = self.filter.updateBatch(gyro, accel)
        return estimates + list(map(self._estimate, t, out["quat6D"], out["bias"], out["biasSigma"]))

    def _batch_readings(self, samples: list[ImuSample]) -> tuple[list, np.ndarray, np.ndarray] | None:
        """(times, gyro (N, 3), accel (N, 3)) in the body frame of the samples `_update_imu` would
        use (a finite gyro; an invalid accelerometer reading as NO_ACCEL), or None when a reading
        is not a 3-vector."""
        readings = stacked_readings(samples)
        if readings is None:
            return None
        gyro, accel = readings
        if self._body_from_imu is not None:
            gyro, accel = (np.array([self._body_from_imu @ row for row in rows]).reshape(-1, 3) for rows in (gyro, accel))
        # finite exactly when `Estimator._to_body` accepts the reading (the same sum)
        accel[~np.isfinite(accel[:, 0] + accel[:, 1] + accel[:, 2])] = NO_ACCEL
        valid = np.isfinite(gyro[:, 0] + gyro[:, 1] + gyro[:, 2])
        times = [s.t for s, keep in zip(samples, valid.tolist()) if keep]
        return times, np.ascontiguousarray(gyro[valid]), np.ascontiguousarray(accel[valid])
