"""The estimators by spec (a registered name or MODULE:CLASS): the one factory the run loop,
replay, bench and sweep call."""

from __future__ import annotations

from estimators.base import Estimator
from testbed.model.registry import Registry

ESTIMATORS = Registry.of_subclasses("estimator", "estimators", Estimator)
NONE = "none"     # no estimator


def check_estimator_spec(spec: str) -> None:
    if spec != NONE:
        ESTIMATORS.check_spec(spec)


def resolve_estimator(spec: str):
    """The estimator class of `spec`, or None for `none`."""
    return None if spec == NONE else ESTIMATORS.resolve(spec)


def make_estimator(spec: str, config) -> Estimator:
    """A fresh estimator: `cls.from_config(config)` (the run's tuning, geometry, gravity and IMU
    mounting) when the class has it, else `cls()`."""
    return ESTIMATORS.build(spec, config)
