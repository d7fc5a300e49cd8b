"""All sensors of a run behind one interface: the run loop calls `update(truth)` once per physics
step and gets every sample that fell due since the previous call, in time order; replays and
estimators consume the same Sample objects.

Timing: a stream of rate f samples at t_k = k / f (k = 0, 1, ...), independent of the physics
step. Each sample reads the latest truth at or before t_k (sample-and-hold, at most one physics
step old; on the first call, the truth given), and carries t_k as its timestamp.
"""

from __future__ import annotations

from operator import attrgetter
from types import SimpleNamespace

from sensors.config import SensorsConfig
from sensors.faults import TIME_EPS
from sensors.motion import MotionCache
from sensors.samples import Sample
from sensors.sensor import SENSORS, Sensor, SensorContext
from testbed.model.truth import Truth


class SensorSuite:
    def __init__(self, sensors: list[Sensor]) -> None:
        self.sensors = sorted(sensors, key=attrgetter("order"))
        self._clocked = [(sensor, sensor.clock) for sensor in self.sensors]
        self._previous: Truth | None = None

    @classmethod
    def from_config(cls, config) -> SensorSuite:
        """Every registered sensor that the run's config asks for."""
        return cls.from_sections(config.sensors, config.run.gravity, config.run.seed)

    @classmethod
    def from_sections(cls, sensors: SensorsConfig, gravity: float, seed: int) -> SensorSuite:
        """The suite from the `[sensors]` section, gravity (m/s^2) and the run's seed alone."""
        config = SimpleNamespace(sensors=sensors, run=SimpleNamespace(gravity=gravity, seed=seed))
        context = SensorContext(seed, sensors.parsed_faults, MotionCache(gravity))
        built = (SENSORS.build(name, config, context) for name in SENSORS.names())
        return cls([sensor for sensor in built if sensor is not None])

    def sensor(self, kind: type[Sensor]) -> Sensor:
        """The suite's sensor of this class."""
        return next(sensor for sensor in self.sensors if isinstance(sensor, kind))

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
