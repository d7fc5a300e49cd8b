"""Cost of an estimator update, per sample type, in microseconds of wall time."""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np

from estimators.base import Estimator
from sensors.samples import Sample


def update_costs(estimator: Estimator, samples: Iterable[Sample]) -> dict[str, dict[str, float]]:
    """Per sample type ("ImuSample", ...): mean, median and 99th percentile of `update` in us."""
    elapsed: dict[str, list[int]] = {}
    for sample in samples:
        start = time.perf_counter_ns()
        estimator.update(sample)
        elapsed.setdefault(type(sample).__name__, []).append(time.perf_counter_ns() - start)
    return {kind: {"mean_us": float(np.mean(ns)) / 1e3, "median_us": float(np.median(ns)) / 1e3,
                   "p99_us": float(np.percentile(ns, 99)) / 1e3}
            for kind, ns in elapsed.items()}
