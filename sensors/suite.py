"""All sensors of a run behind one interface: the run loop calls `update(truth)` once per physics
step and gets every sample that fell due since the previous call, in time order; replays and
estimators consume the same Sample objects.

Timing: a stream of rate f samples at t_k = k / f (k = 0, 1, ...), independent of the physics
step. Each sample reads the latest truth at or before t_k (sample-and-hold, at most one physics
step old; on the first call, the truth given), and carries t_k as its timestamp.
"""

from __future__ import annotations

from operator import attrgetter
from typing import TYPE_CHECKING, Protocol

from sensors.accel_array import AccelArray
from sensors.config import SensorsConfig
from sensors.encoders import Encoders
from sensors.faults import TIME_EPS
from sensors.foot import FootSensors
from sensors.imu import Imu
from sensors.motion import MotionCache
from sensors.samples import Sample
from sensors.sampling import SampleClock
from testbed.model.truth import Truth


class Sensor(Protocol):
    clock: SampleClock

    def samples_at(self, truth: Truth, t: float) -> list[Sample]:
        """The samples this sensor emits at time t, reading `truth`."""


class SensorSuite:
    def __init__(self, config: SensorsConfig, gravity: float, seed: int) -> None:
        self.config = config
        motion = MotionCache(gravity)
        faults = config.parsed_faults
        self.imu = Imu(config.imu, seed, faults, motion)
        self.accel_array = (AccelArray(config.accel_array, config.imu.accel, seed, faults, motion)
                            if len(config.accel_array.member_positions) else None)
        self.encoders = Encoders(config.encoder, seed, faults)
        self.foot = FootSensors(config.foot, seed, faults)
        self._sensors: list[Sensor] = [s for s in (self.imu, self.accel_array, self.encoders, self.foot) if s is not None]
        self._clocked = [(sensor, sensor.clock) for sensor in self._sensors]
        self._previous: Truth | None = None

    @classmethod
    def from_config(cls, config) -> SensorSuite:
        """The suite of a run: its sensors config, gravity and seed."""
        return cls(config.sensors, config.run.gravity, config.run.seed)

    def update(self, truth: Truth) -> list[Sample]:
        """Samples with t in (previous truth.t, truth.t], sorted by t (ties: IMU, array, encoders, feet)."""
        samples: list[Sample] = []
        now, previous = truth.t, self._previous
        due_by = now + TIME_EPS
        for sensor, clock in self._clocked:
            if clock.next_time > due_by:    # the usual case of the slower sensors: nothing due
                continue
            for t in clock.due(now):
                # The latest truth at or before t (on the first call, the truth given).
                source = truth if previous is None or t >= now - TIME_EPS else previous
                samples += sensor.samples_at(source, t)
        self._previous = truth
        if len(samples) > 1:
            samples.sort(key=_SAMPLE_TIME)
        return samples


_SAMPLE_TIME = attrgetter("t")
