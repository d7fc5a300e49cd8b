"""The sensor interface and its registry.

A sensor emits timestamped samples at its own rate: the suite asks each sensor's `clock` which
sample times fell due since the previous physics step and calls `samples_at(truth, t)` for each.
Every registered sensor (entry point group `hexapod_testbed.sensors`) is part of every run;
`from_config` returns None for one that the config leaves out.
"""

from __future__ import annotations

import abc
from typing import ClassVar, NamedTuple

from sensors.faults import Fault
from sensors.motion import MotionCache
from sensors.samples import Sample
from sensors.sampling import SampleClock
from testbed.model.registry import Registry
from testbed.model.truth import Truth


class SensorContext(NamedTuple):
    """What every sensor of a run shares: the run's seed (each sensor derives its own stream from
    it), the parsed fault specs, and the body motion computed once per truth."""
    seed: int
    faults: tuple[Fault, ...]
    motion: MotionCache


class Sensor(abc.ABC):
    order: ClassVar[int] = 100      # samples of equal time are delivered in this order (IMU first)
    clock: SampleClock

    @classmethod
    @abc.abstractmethod
    def from_config(cls, config, context: SensorContext) -> "Sensor | None":
        """The sensor of a run (the run's Config), or None when the config leaves it out."""

    @abc.abstractmethod
    def samples_at(self, truth: Truth, t: float) -> list[Sample]:
        """The samples this sensor emits at time t, reading `truth`."""


SENSORS = Registry.of_subclasses("sensor", "sensors", Sensor)
