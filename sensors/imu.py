"""IMU at a pose on the body: a 3-axis accelerometer (specific force at its point, lever arm
included) and a 3-axis gyro, sampled together. Default parameters: Bosch BMI088 (docs/sensors.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.linalg import block_diag

from sensors.config import ImuConfig
from sensors.faults import Fault, FaultInjector
from sensors.inertial_errors import InertialChannels, TriadErrors, corrupt_values, digitize_rows
from sensors.motion import BodyMotion, MotionCache, body_motion_arrays
from sensors.samples import ImuSample
from sensors.sensor import Sensor, SensorContext
from sensors.sampling import SampleClock, measure, sensor_seed
from testbed.model.truth import Truth


# The fault-free reading's constants, fields by name (`_imu_reading`).
IMU_READING = np.dtype([
    ("position", "f8", 3),      # m, body frame: the accelerometer's point
    ("gravity", "f8"),          # m/s^2
    ("lsb", "f8", 6), ("lowest", "f8", 6), ("highest", "f8", 6),     # InertialChannels' digitizing
])


class Imu(Sensor):
    order = 0

    def __init__(self, config: ImuConfig, run_seed: int, faults: tuple[Fault, ...], motion: MotionCache) -> None:
        self.config = config
        self.clock = SampleClock(config.rate)
        self._motion = motion
        self._position = np.array(config.position, dtype=float)
        sensor_from_body = config.body_from_sensor.T
        triads = [TriadErrors(config.accel, config.rate, sensor_seed(run_seed, "imu.accel")),
                  TriadErrors(config.gyro, config.rate, sensor_seed(run_seed, "imu.gyro"))]
        self.channels = InertialChannels(triads, frame=block_diag(sensor_from_body, sensor_from_body))
        self._faults = FaultInjector(faults, "imu", 6, self.channels.full_scale)
        self._fault_free = not self._faults
        self._constants = np.zeros(1, dtype=IMU_READING)
        constants, channels = self._constants[0], self.channels
        constants["position"], constants["gravity"] = self._position, motion.gravity
        constants["lsb"], constants["lowest"], constants["highest"] = channels.lsb, channels.lowest, channels.highest

    @classmethod
    def from_config(cls, config, context: SensorContext) -> "Imu":
        return cls(config.sensors.imu, context.seed, context.faults, context.motion)

    def body_values(self, motion: BodyMotion) -> np.ndarray:
        """(6,) noise-free specific force at the IMU point and angular velocity, body frame."""
        values = np.empty(6)
        values[:3] = motion.specific_force_at(self._position)
        values[3:] = motion.angular_velocity
        return values

    def samples_at(self, truth: Truth, t: float) -> list[ImuSample]:
        if self._fault_free:
            out = _imu_reading(truth.body_rotation, truth.body_linear_acceleration, truth.body_angular_velocity,
                               truth.body_angular_acceleration, self._constants, self.channels.gain,
                               self.channels.next_errors())
        else:
            out, dropped = measure(self.channels, self._faults, t, self.body_values(self._motion(truth)))
            if dropped is not None and dropped.all():
                return []
        return [ImuSample(t, out[:3], out[3:])]

    def record(self, truth: Truth, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times, accel (n, 3) and gyro (n, 3) of n samples from t = 0 of a body held in `truth`'s
        state: the vectorised path (same noise streams as samples_at, faults not applied) for long
        still records such as the Allan deviation. Use it on a fresh Imu."""
        out = self.channels.record(self.body_values(BodyMotion(truth, self._motion.gravity)), n)
        return np.arange(n) / self.config.rate, out[:, :3], out[:, 3:]


# Compiled: the fault-free IMU sample at 1 kHz in one call, through the same compiled steps as the
# faulted path (true values, errors, digitizing), which numpy spent a dozen small calls on.
@njit(cache=True)
def _imu_reading(rotation, acceleration, angular_velocity, angular_acceleration, constants, gain, errors):
    """The reading of the IMU whose IMU_READING record is `constants`, through the channels'
    `gain` and with their additive `errors`."""
    c = constants[0]
    force, omega, lever = body_motion_arrays(rotation, acceleration, angular_velocity, angular_acceleration,
                                             c.gravity)
    values = np.empty(6)
    values[:3] = force + lever @ c.position
    values[3:] = omega
    return digitize_rows(corrupt_values(gain, values, errors).reshape(1, -1), c.lsb, c.lowest, c.highest)[0]
