"""Accelerometer array: N 3-axis accelerometers of the IMU's accelerometer model at body points,
axes parallel to the body axes, sampled together. Each reads the specific force at its own point,
so that estimators can separate gravity from the rotational terms of the body's motion.
"""

from __future__ import annotations

import numpy as np

from sensors.config import AccelArrayConfig, InertialAxesConfig
from sensors.faults import Fault, FaultInjector
from sensors.inertial_errors import InertialChannels, TriadErrors
from sensors.motion import MotionCache
from sensors.samples import AccelSample
from sensors.sensor import Sensor, SensorContext
from sensors.sampling import SampleClock, measure, sensor_seed
from testbed.model.truth import Truth


class AccelArray(Sensor):
    order = 1

    def __init__(self, config: AccelArrayConfig, accel: InertialAxesConfig, run_seed: int,
                 faults: tuple[Fault, ...], motion: MotionCache) -> None:
        self.clock = SampleClock(config.rate)
        self._motion = motion
        self._positions = config.member_positions
        self.members = len(self._positions)
        triads = [TriadErrors(accel, config.rate, sensor_seed(run_seed, f"accel_array.{i}")) for i in range(self.members)]
        self.channels = InertialChannels(triads, frame=np.eye(3 * self.members))
        self._faults = FaultInjector(faults, "accel_array", 3, self.channels.full_scale, members=self.members)

    @classmethod
    def from_config(cls, config, context: SensorContext) -> "AccelArray | None":
        sensors = config.sensors
        if not len(sensors.accel_array.member_positions):
            return None
        return cls(sensors.accel_array, sensors.imu.accel, context.seed, context.faults, context.motion)

    def samples_at(self, truth: Truth, t: float) -> list[AccelSample]:
        true_values = self._motion(truth).specific_force_at(self._positions).ravel()
        out, dropped = measure(self.channels, self._faults, t, true_values)
        per_member = out.reshape(self.members, 3)
        if dropped is None:
            return [AccelSample(t, i, per_member[i]) for i in range(self.members)]
        lost = dropped.reshape(self.members, 3).all(axis=1)
        return [AccelSample(t, i, per_member[i]) for i in range(self.members) if not lost[i]]
