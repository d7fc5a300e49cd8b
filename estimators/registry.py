"""The estimators by name, and the one factory the run loop and replay call."""

from __future__ import annotations

from estimators.base import Estimator
from estimators.baselines import MadgwickEstimator, MahonyEstimator, VqfEstimator
from estimators.complementary import ComplementaryEstimator
from estimators.config import ESTIMATOR_NAMES
from estimators.ekf import EkfEstimator
from estimators.ukf import UkfEstimator
from testbed.config import Config
from testbed.errors import UserError

ESTIMATORS: dict[str, type[Estimator]] = {
    cls.name: cls for cls in (EkfEstimator, UkfEstimator, ComplementaryEstimator, MadgwickEstimator,
                              MahonyEstimator, VqfEstimator)
}
assert tuple(ESTIMATORS) == ESTIMATOR_NAMES


def make_estimator(name: str, config: Config) -> Estimator:
    """A fresh estimator with the run's tuning (config.estimators), robot geometry (config.robot),
    gravity (config.run) and IMU mounting (config.sensors.imu)."""
    if name not in ESTIMATORS:
        raise UserError(f"unknown estimator '{name}' (choose from {', '.join(ESTIMATORS)})")
    return ESTIMATORS[name].from_config(config)
