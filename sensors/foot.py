"""Foot force sensors: the normal force on each foot with Gaussian noise, saturating at
+-full_scale, and a contact flag with hysteresis: it rises above contact_on and falls below
contact_off. A dropped (NaN) reading has no contact.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sensors.config import FootConfig
from sensors.faults import Fault, FaultInjector
from sensors.samples import FootSample
from sensors.sensor import Sensor, SensorContext
from sensors.sampling import RowBuffer, SampleClock, gaussian_rows, measure, sensor_seed
from testbed.model.truth import NUM_LEGS, Truth


class FootSensors(Sensor):
    order = 3

    def __init__(self, config: FootConfig, run_seed: int, faults: tuple[Fault, ...]) -> None:
        self.config = config
        self.clock = SampleClock(config.rate)
        rng = np.random.default_rng(sensor_seed(run_seed, "foot"))
        self._noise = RowBuffer(gaussian_rows(rng, config.noise, NUM_LEGS)) if config.noise > 0 else None
        self._faults = FaultInjector(faults, "foot", NUM_LEGS, np.full(NUM_LEGS, config.full_scale))
        self._contact = np.zeros(NUM_LEGS, dtype=bool)
        self._plain = self._noise is not None and not self._faults    # noisy, no fault: one compiled call

    @classmethod
    def from_config(cls, config, context: SensorContext) -> "FootSensors":
        return cls(config.sensors.foot, context.seed, context.faults)

    def corrupt(self, forces: np.ndarray) -> np.ndarray:
        return forces + self._noise.next() if self._noise else np.array(forces, dtype=float)

    def digitize(self, raw: np.ndarray) -> np.ndarray:
        return saturated(raw, self.config.full_scale)

    def samples_at(self, truth: Truth, t: float) -> list[FootSample]:
        if self._plain:
            config = self.config
            forces, self._contact = _noisy_reading(truth.foot_normal_forces, self._noise.next(), config.full_scale,
                                                   self._contact, config.contact_on, config.contact_off)
            return [FootSample(t, forces, self._contact)]
        forces, dropped = measure(self, self._faults, t, truth.foot_normal_forces)
        if dropped is not None and dropped.all():
            return []
        # A new array at each sample: the sample may share it.
        self._contact = contact_hysteresis(forces, self._contact, self.config.contact_on, self.config.contact_off)
        return [FootSample(t, forces, self._contact)]


# Both compiled: they run at every foot sample, where numpy's per-call cost on six values dominates.
@njit(cache=True)
def saturated(raw: np.ndarray, full_scale: float) -> np.ndarray:
    """np.minimum(np.maximum(raw, -full_scale), full_scale), NaN kept."""
    out = raw.copy()
    for i in range(len(raw)):
        if out[i] < -full_scale:
            out[i] = -full_scale
        elif out[i] > full_scale:
            out[i] = full_scale
    return out


@njit(cache=True)
def contact_hysteresis(forces: np.ndarray, contact: np.ndarray, on: float, off: float) -> np.ndarray:
    """Contact flags rising above `on`, falling below `off` (NaN compares False both ways, so a
    dropped foot reads no contact)."""
    out = np.empty(len(forces), np.bool_)
    for i in range(len(forces)):
        out[i] = forces[i] > on or (contact[i] and forces[i] >= off)
    return out


@njit(cache=True)
def _noisy_reading(forces: np.ndarray, noise: np.ndarray, full_scale: float, contact: np.ndarray, on: float,
                   off: float) -> tuple[np.ndarray, np.ndarray]:
    """A fault-free sample in one call: `measure`'s corrupt and digitize (saturated(forces + noise)),
    then the contact flags (a new array) by contact_hysteresis."""
    readings = saturated(forces + noise, full_scale)
    return readings, contact_hysteresis(readings, contact, on, off)
