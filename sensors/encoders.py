"""Joint encoders: absolute angle of each of the 18 joints with Gaussian noise, quantized to `bits`
over one turn (2 pi / 2^bits per count) and wrapped to [-pi, pi), like a smart servo's encoder.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sensors.config import EncoderConfig
from sensors.faults import Fault, FaultInjector
from sensors.samples import EncoderSample
from sensors.sensor import Sensor, SensorContext
from sensors.sampling import RowBuffer, SampleClock, gaussian_rows, measure, sensor_seed
from testbed.model.truth import NUM_JOINTS, Truth


class Encoders(Sensor):
    order = 2

    def __init__(self, config: EncoderConfig, run_seed: int, faults: tuple[Fault, ...]) -> None:
        self.config = config
        self.clock = SampleClock(config.rate)
        self.lsb = config.lsb
        self._counts_per_turn = 2**config.bits
        rng = np.random.default_rng(sensor_seed(run_seed, "encoder"))
        self._noise = RowBuffer(gaussian_rows(rng, config.noise, NUM_JOINTS)) if config.noise > 0 else None
        # A spike of one half turn by default: the worst a wrapped angle can be off.
        self._faults = FaultInjector(faults, "encoder", NUM_JOINTS, np.full(NUM_JOINTS, math.pi))
        self._plain = self._noise is not None and not self._faults    # noisy, no fault: one compiled call

    @classmethod
    def from_config(cls, config, context: SensorContext) -> "Encoders":
        return cls(config.sensors.encoder, context.seed, context.faults)

    def corrupt(self, angles: np.ndarray) -> np.ndarray:
        return angles + self._noise.next() if self._noise else np.array(angles, dtype=float)

    def digitize(self, raw: np.ndarray) -> np.ndarray:
        return wrapped_counts(raw, self.lsb, self._counts_per_turn)

    def samples_at(self, truth: Truth, t: float) -> list[EncoderSample]:
        if self._plain:
            return [EncoderSample(t, _noisy_counts(truth.joint_positions, self._noise.next(), self.lsb,
                                                   self._counts_per_turn))]
        out, dropped = measure(self, self._faults, t, truth.joint_positions)
        if dropped is not None and dropped.all():
            return []
        return [EncoderSample(t, out)]


# Compiled: it runs at every encoder sample, where numpy's per-call cost on 18 values dominates.
# Integer-valued floats throughout until the last product: the counts are exact
# (rint, then a float modulo).
@njit(cache=True)
def wrapped_counts(raw: np.ndarray, lsb: float, counts_per_turn: int) -> np.ndarray:
    """Angles quantized to `lsb` and wrapped to [-pi, pi): counts in [-half, half) turns, times lsb."""
    half = counts_per_turn // 2
    out = np.empty_like(raw)
    for i in range(len(raw)):
        out[i] = ((np.rint(raw[i] / lsb) + half) % counts_per_turn - half) * lsb
    return out


@njit(cache=True)
def _noisy_counts(angles: np.ndarray, noise: np.ndarray, lsb: float, counts_per_turn: int) -> np.ndarray:
    """wrapped_counts(angles + noise): `measure`'s corrupt and digitize of a fault-free encoder."""
    return wrapped_counts(angles + noise, lsb, counts_per_turn)
