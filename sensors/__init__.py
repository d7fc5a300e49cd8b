"""Sensor models: functions of ground truth plus a seeded random generator.

The sample types are what estimators and controllers receive."""

import testbed  # noqa: F401 - first: it chooses numba's cache folder before numba is imported
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from sensors.sensor import Sensor, SensorContext

__all__ = ["AccelSample", "EncoderSample", "FootSample", "ImuSample", "Sample", "Sensor", "SensorContext"]
