"""Errors of MEMS accelerometers and gyros, three axes at a time.

Per axis: reading = (I + S + M) true + turn-on bias + flicker bias + bias random walk + white noise,
then saturation and quantization to a signed `bits`-bit count. The random parts and the Allan
deviation they produce (IEEE Std 952-1997, Annex C), with tau the averaging time:

    white noise, density N         sigma_A = N / sqrt(tau)            per-sample sigma N sqrt(rate)
    flicker bias, instability B    sigma_A = B sqrt(2 ln 2 / pi) = 0.664 B, flat
    bias random walk, K            sigma_A = K sqrt(tau / 3)

Flicker (1/f) noise has no finite-state form. It is approximated by white noise through a
pole-zero ("pinking") filter: real poles at correlation times spaced two per decade over
FLICKER_BAND, a zero midway (geometrically) between each pair of poles, so that |H(f)|^2 falls
as 1/f inside the band (within 0.2 %) and as 1/f^2 above it. Its gain makes the two-sided power
spectral density B^2 / (2 pi f), the spectrum whose Allan floor is 0.664 B (within 0.1 % for
0.3 s <= tau <= 1e5 s).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import block_diag
from numba import njit
from scipy.signal import lfilter, sosfilt

from sensors.config import InertialAxesConfig
from sensors.sampling import RowBuffer

FLICKER_BAND = (1e-2, 1e6)      # s, shortest and longest time constant of the flicker filter's poles
FLICKER_PER_DECADE = 2
RECORD_CHUNK = 1 << 16          # samples per block on the vectorised path (bounds its memory)


def flicker_filter(bias_instability: float, dt: float) -> np.ndarray:
    """Sections (scipy sos format) turning unit white noise at interval dt into flicker noise of
    instability B: two-sided spectral density dt |H(f)|^2 = B^2 / (2 pi f) inside FLICKER_BAND.

    One first-order section per pole: poles within 1e-9 of 1 lose their place if multiplied out
    into biquads, and |1 - c e^(-i w)|^2 = (1 - c)^2 + 4 c sin^2(w / 2) keeps the gain exact.
    """
    low, high = np.log10(FLICKER_BAND)
    pole_times = 10.0 ** np.arange(low, high + 1e-9, 1.0 / FLICKER_PER_DECADE)
    zero_times = pole_times[1:] / 10.0 ** (0.5 / FLICKER_PER_DECADE)
    zeros = np.append(np.exp(-dt / zero_times), 0.0)    # one zero fewer than poles: 1/f^2 above the band
    poles = np.exp(-dt / pole_times)
    frequency = np.logspace(-high + 1, -low - 1, 50) / (2 * np.pi)     # the band's inner decades, Hz
    half_angle = np.sin(np.pi * frequency * dt)[:, None] ** 2
    one_minus_zero = np.append(-np.expm1(-dt / zero_times), 1.0)
    power = (np.prod(one_minus_zero**2 + 4 * zeros * half_angle, axis=1)
             / np.prod(np.expm1(-dt / pole_times) ** 2 + 4 * poles * half_angle, axis=1))
    gain = math.sqrt(math.exp(np.mean(np.log(bias_instability**2 / (2 * np.pi * frequency) / (dt * power)))))
    sections = np.zeros((len(poles), 6))
    sections[:, 0], sections[:, 1], sections[:, 3], sections[:, 4] = 1.0, -zeros, 1.0, -poles
    sections[0, :2] *= gain
    return sections


class TriadErrors:
    """Systematic and random errors of the three axes of one accelerometer or gyro."""

    def __init__(self, config: InertialAxesConfig, rate: float, seed: np.random.SeedSequence) -> None:
        constants, white, flicker, walk = (np.random.default_rng(s) for s in seed.spawn(4))
        self.config = config
        self.turn_on_bias = constants.normal(0.0, config.turn_on_bias, 3)
        self.matrix = self._error_matrix(constants, config)
        dt = 1.0 / rate
        self._white, self._white_sigma = white, config.noise_density * math.sqrt(rate)
        self._flicker = flicker
        self._flicker_sections = flicker_filter(config.bias_instability, dt) if config.bias_instability > 0 else None
        self._flicker_state = None if self._flicker_sections is None else np.zeros((len(self._flicker_sections), 2, 3))
        self._walk, self._walk_step = walk, config.rate_random_walk * math.sqrt(dt)
        self._walk_state = np.zeros((1, 3))

    @staticmethod
    def _error_matrix(rng: np.random.Generator, config: InertialAxesConfig) -> np.ndarray:
        """I + diag(scale-factor errors) + off-diagonal cross-axis terms (small-angle misalignment)."""
        matrix = np.eye(3) + np.diag(rng.normal(0.0, config.scale_factor, 3))
        off_diagonal = ~np.eye(3, dtype=bool)
        matrix[off_diagonal] += rng.normal(0.0, config.misalignment, 6)
        return matrix

    def draw(self, n: int) -> np.ndarray:
        """(n, 3) additive errors of the next n samples: turn-on bias, flicker, random walk, white noise."""
        errors = np.tile(self.turn_on_bias, (n, 1))
        if self._white_sigma > 0:
            errors += self._white_sigma * self._white.standard_normal((n, 3))
        if self._flicker_sections is not None:
            shocks = self._flicker.standard_normal((n, 3))
            flicker, self._flicker_state = sosfilt(self._flicker_sections, shocks, axis=0, zi=self._flicker_state)
            errors += flicker
        if self._walk_step > 0:
            steps = self._walk.standard_normal((n, 3))
            walk, self._walk_state = lfilter([self._walk_step], [1.0, -1.0], steps, axis=0, zi=self._walk_state)
            errors += walk
        return errors


class InertialChannels:
    """Several triads sampled together as one vector of 3 k channels (the IMU: accel then gyro).

    `frame` maps the true values, given in the body frame, to the sensor axes; it is folded into
    the error matrix once, so that a sample costs one matrix-vector product.
    """

    def __init__(self, triads: list[TriadErrors], frame: np.ndarray) -> None:
        self.triads = triads
        configs = [triad.config for triad in triads]
        self.gain = block_diag(*(triad.matrix for triad in triads)) @ frame
        self.lsb = np.repeat([c.lsb for c in configs], 3)
        self.full_scale = np.repeat([c.range for c in configs], 3)
        half = np.repeat([2.0 ** (c.bits - 1) for c in configs], 3)
        self.lowest, self.highest = -half, half - 1.0     # two's-complement counts
        self._rows = RowBuffer(self.draw)

    def draw(self, n: int) -> np.ndarray:
        return np.hstack([triad.draw(n) for triad in self.triads])

    def next_errors(self) -> np.ndarray:
        """The additive errors (3 k,) of the next sample."""
        return self._rows.next()

    def corrupt(self, true_values: np.ndarray) -> np.ndarray:
        return corrupt_values(self.gain, true_values, self._rows.next())

    def digitize(self, raw: np.ndarray) -> np.ndarray:
        """Saturated, quantized readings: rint(raw / lsb) clamped to the signed counts, times lsb."""
        return digitize_rows(raw.reshape(-1, len(self.lsb)), self.lsb, self.lowest, self.highest).reshape(raw.shape)

    def record(self, true_values: np.ndarray, n: int) -> np.ndarray:
        """(n, 3 k) outputs of n samples of constant true values: the same errors and digitizing
        as n calls of corrupt and digitize on a fresh instance, vectorised."""
        out = np.empty((n, len(self.lsb)))
        analog = self.gain @ true_values
        for start in range(0, n, RECORD_CHUNK):
            stop = min(n, start + RECORD_CHUNK)
            out[start:stop] = self.digitize(analog + self.draw(stop - start))
        return out


@njit(cache=True)
def corrupt_values(gain, true_values, errors):
    """gain @ true_values + errors."""
    return gain @ true_values + errors


# Compiled: it runs at every IMU sample, on six values. The same
# function digitizes the vectorised `record` path, so both paths give identical readings.
@njit(cache=True)
def digitize_rows(raw, lsb, lowest, highest):
    out = np.empty_like(raw)
    for row in range(raw.shape[0]):
        for channel in range(raw.shape[1]):
            counts = np.rint(raw[row, channel] / lsb[channel])
            if counts < lowest[channel]:
                counts = lowest[channel]
            elif counts > highest[channel]:
                counts = highest[channel]
            out[row, channel] = counts * lsb[channel]
    return out
