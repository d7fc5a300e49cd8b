"""A user's sensor: a barometric altimeter on the body, 50 Hz, 2 cm white noise.

A sensor joins every run once it is registered, in its package's pyproject.toml:

    [project.entry-points."hexapod_testbed.sensors"]
    barometer = "my_sensor:Barometer"

Its samples are recorded on their own topic (`/sensors/my_sensor.BaroSample`) and replayed to
estimators, which ignore sample types they do not know.
"""

from dataclasses import dataclass

import numpy as np

from sensors.sampling import SampleClock, sensor_seed
from sensors.sensor import Sensor, SensorContext

RATE = 50.0         # Hz
NOISE = 0.02        # m, standard deviation


@dataclass(frozen=True)
class BaroSample:
    t: float
    altitude: float     # m above the start height of the body


class Barometer(Sensor):
    order = 10          # after the built-in sensors at equal times

    def __init__(self, seed: int):
        self.clock = SampleClock(RATE)
        self.rng = np.random.default_rng(sensor_seed(seed, "barometer"))
        self.start_height = None

    @classmethod
    def from_config(cls, config, context: SensorContext) -> "Barometer":
        return cls(context.seed)

    def samples_at(self, truth, t):
        height = float(truth.body_position[2])
        if self.start_height is None:
            self.start_height = height
        return [BaroSample(t, height - self.start_height + NOISE * float(self.rng.standard_normal()))]
