"""A user's estimator: a complementary filter on roll and pitch.

    PYTHONPATH=examples testbed run --estimator my_estimator:MyComplementary --gait tripod --duration 10

The gyro is integrated and pulled towards the accelerometer's gravity direction with a small gain;
encoder and foot samples are ignored (the base class drops sample types it does not handle).
"""

import math

import numpy as np

from estimators import Estimate, Estimator
from sensors import ImuSample


class MyComplementary(Estimator):
    """Roll and pitch from gyro integration, corrected by the accelerometer's tilt."""

    def __init__(self, gain: float = 0.002):
        self.gain = gain            # share of the accelerometer's tilt per IMU sample
        self.roll = self.pitch = 0.0
        self.last_t = None

    @classmethod
    def from_config(cls, config) -> "MyComplementary":
        return cls()

    def update(self, sample):
        if not isinstance(sample, ImuSample):
            return None
        gyro, accel = np.asarray(sample.gyro, float), np.asarray(sample.accel, float)
        if not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel))):
            return None
        dt = 0.0 if self.last_t is None else sample.t - self.last_t
        self.last_t = sample.t
        accel_roll = math.atan2(accel[1], accel[2])
        accel_pitch = math.atan2(-accel[0], math.hypot(accel[1], accel[2]))
        k = self.gain
        self.roll = (1 - k) * (self.roll + gyro[0] * dt) + k * accel_roll
        self.pitch = (1 - k) * (self.pitch + gyro[1] * dt) + k * accel_pitch
        return Estimate(t=sample.t, quaternion=_quaternion(self.roll, self.pitch), roll=self.roll,
                        pitch=self.pitch, yaw=0.0)


def _quaternion(roll: float, pitch: float) -> np.ndarray:
    """world_from_body for R = Ry(pitch) Rx(roll), scipy order (x, y, z, w)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return np.array([sr * cp, cr * sp, -sr * sp, cr * cp])
