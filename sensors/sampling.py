"""What every sensor stream shares: its sample clock, its seed, pre-drawn noise, the measurement steps."""

from __future__ import annotations

import zlib
from typing import Callable, Protocol

import numpy as np

from sensors.faults import TIME_EPS, FaultInjector

NOISE_BLOCK = 1024      # rows of noise drawn at once: one numpy call per block instead of per sample
_SENSORS_KEY = zlib.crc32(b"sensors")   # keeps sensor streams apart from other users of the run seed


def sensor_seed(run_seed: int, name: str) -> np.random.SeedSequence:
    """The seed of one sensor, derived from its name: adding a sensor leaves the others' streams alone."""
    return np.random.SeedSequence(run_seed, spawn_key=(_SENSORS_KEY, zlib.crc32(name.encode())))


class SampleClock:
    """Sample times k / rate (k = 0, 1, ...), computed by division so that they never drift."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self._next = 0
        self.next_time = 0.0     # the next sample time, not handed out yet

    def due(self, t: float) -> list[float]:
        """The sample times up to `t` not handed out before, in order."""
        times = []
        while self.next_time <= t + TIME_EPS:
            times.append(self.next_time)
            self._next += 1
            self.next_time = self._next / self.rate
        return times


class RowBuffer:
    """Hands out the rows of arrays drawn `NOISE_BLOCK` rows at a time by `draw(n)`.

    `draw` must be block-size invariant (n rows then m rows equal n + m rows at once), so the
    stream of rows does not depend on how it is cut into blocks.
    """

    def __init__(self, draw: Callable[[int], np.ndarray]) -> None:
        self._draw = draw
        self._rows = np.empty((0, 0))
        self._index = 0

    def next(self) -> np.ndarray:
        if self._index == len(self._rows):
            self._rows = self._draw(NOISE_BLOCK)
            self._index = 0
        row = self._rows[self._index]
        self._index += 1
        return row


def gaussian_rows(rng: np.random.Generator, sigma: float, width: int) -> Callable[[int], np.ndarray]:
    """draw(n): n rows of `width` independent N(0, sigma^2) values (block-size invariant)."""
    return lambda n: sigma * rng.standard_normal((n, width))


class MeasurementModel(Protocol):
    def corrupt(self, true_values: np.ndarray) -> np.ndarray:
        """The analog reading: true values with the sensor's errors, a new array."""

    def digitize(self, raw: np.ndarray) -> np.ndarray:
        """The digital output: saturated and quantized."""


def measure(model: MeasurementModel, faults: FaultInjector, t: float,
            true_values: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """One sample vector through errors, analog faults, digitizing and digital faults.

    Returns the output and the mask of its dropped (NaN) channels, or None when nothing dropped.
    """
    raw = model.corrupt(true_values)
    if not faults:
        return model.digitize(raw), None
    out, dropped = faults.hold(t, model.digitize(faults.disturb(t, raw)))
    return out, dropped if dropped.any() else None
