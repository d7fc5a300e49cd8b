"""Overlapping Allan deviation and the fit of its noise terms (IEEE Std 952-1997, Annex C).

For rate samples y_k at interval dt, with x the running integral of y and tau = m dt:
    sigma^2(tau) = sum_k (x_{k+2m} - 2 x_{k+m} + x_k)^2 / (2 tau^2 (n - 2m))      (overlapping)
The noise terms of the sensor model add as variances:
    sigma^2(tau) = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3
N: noise density (white noise; the N / sqrt(tau) line read at tau = 1 s), B: bias instability
(the flicker floor is 0.664 B), K: rate random walk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

FLICKER_FLOOR = math.sqrt(2 * math.log(2) / math.pi)    # 0.664: Allan floor / bias instability


@dataclass(frozen=True)
class NoiseTerms:
    noise_density: float        # unit/sqrt(Hz)
    bias_instability: float     # unit
    rate_random_walk: float     # unit/sqrt(s)


def cluster_sizes(n: int, per_decade: int = 10, max_fraction: float = 0.1) -> np.ndarray:
    """Log-spaced averaging lengths m = 1 ... max_fraction n (longer ones average too few clusters)."""
    longest = max(1, int(max_fraction * n))
    return np.unique(np.round(np.logspace(0, math.log10(longest), int(per_decade * math.log10(longest)) + 1)).astype(int))


def allan_deviation(samples: np.ndarray, rate: float, sizes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of (n,) or (n, k) samples at `rate` Hz.

    Returns tau (s) and the deviation per tau (and per column), in the samples' unit.
    """
    samples = np.asarray(samples, dtype=float)
    sizes = cluster_sizes(len(samples)) if sizes is None else np.asarray(sizes)
    dt = 1.0 / rate
    # The running integral, mean removed first so that a large constant (gravity) costs no precision.
    integral = np.concatenate((np.zeros((1,) + samples.shape[1:]), np.cumsum((samples - samples.mean(axis=0)) * dt, axis=0)))
    second_difference = np.empty_like(integral)    # reused: fresh arrays this large cost page faults
    deviations = []
    for m in sizes:
        d = second_difference[:len(integral) - 2 * m]
        np.subtract(integral[2 * m:], integral[m:-m], out=d)
        d -= integral[m:-m]
        d += integral[:-2 * m]
        mean_square = np.einsum("i...,i...->...", d, d) / len(d)
        deviations.append(np.sqrt(mean_square / 2.0) / (m * dt))
    return sizes * dt, np.array(deviations)


def model_deviation(tau: np.ndarray, terms: NoiseTerms) -> np.ndarray:
    """Allan deviation that the noise terms predict."""
    variance = (terms.noise_density**2 / tau + (FLICKER_FLOOR * terms.bias_instability) ** 2
                + terms.rate_random_walk**2 * tau / 3.0)
    return np.sqrt(variance)


def fit_noise_terms(tau: np.ndarray, deviation: np.ndarray, tau_max: float | None = None) -> NoiseTerms:
    """N, B and K by non-negative least squares of the Allan variance on relative residuals.

    `deviation` may have one column per axis of the same sensor: their variances are averaged.
    `tau_max` limits the fit to well-averaged taus (the estimate at tau scatters as sqrt(tau / T)).
    """
    variance = np.asarray(deviation, dtype=float) ** 2
    if variance.ndim == 2:
        variance = variance.mean(axis=1)
    keep = np.ones(len(tau), dtype=bool) if tau_max is None else tau <= tau_max
    tau, variance = tau[keep], variance[keep]
    basis = np.column_stack((1.0 / tau, np.full(len(tau), FLICKER_FLOOR**2), tau / 3.0))
    coefficients, _ = nnls(basis / variance[:, None], np.ones(len(tau)))
    noise_density, bias_instability, rate_random_walk = np.sqrt(coefficients)
    return NoiseTerms(float(noise_density), float(bias_instability), float(rate_random_walk))
