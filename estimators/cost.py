"""Cost of an estimator update, per sample type, in microseconds of wall time.

On a shared machine a single update is now and then preempted for milliseconds, which ruins a mean;
the median of many updates is the robust figure, and `per_simulated_ms` folds the medians of the
sample types with their counts into the cost of one simulated millisecond.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np

from estimators.base import Estimate, Estimator
from sensors.samples import Sample


def timed_run(estimator: Estimator, samples: Iterable[Sample]) -> tuple[list[Estimate], dict[str, np.ndarray]]:
    """run_estimator, also returning the wall time of every update in ns, per sample type."""
    estimates: list[Estimate] = []
    elapsed: dict[str, list[int]] = {}
    clock = time.perf_counter_ns
    for sample in samples:
        start = clock()
        estimate = estimator.update(sample)
        elapsed.setdefault(type(sample).__name__, []).append(clock() - start)
        if estimate is not None:
            estimates.append(estimate)
    return estimates, {kind: np.array(ns) for kind, ns in elapsed.items()}


def summarise(elapsed: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Per sample type: count, mean, median and 99th percentile of the update time in us."""
    return {kind: {"count": int(len(ns)), "mean_us": float(np.mean(ns)) / 1e3,
                   "median_us": float(np.median(ns)) / 1e3, "p99_us": float(np.percentile(ns, 99)) / 1e3}
            for kind, ns in elapsed.items()}


def per_simulated_ms(costs: dict[str, dict[str, float]], simulated_s: float) -> float:
    """us of estimator work per simulated millisecond, from the median cost of each sample type."""
    return sum(c["median_us"] * c["count"] for c in costs.values()) / (simulated_s * 1e3)


def update_costs(estimator: Estimator, samples: Iterable[Sample]) -> dict[str, dict[str, float]]:
    """Per sample type ("ImuSample", ...): count, mean, median and 99th percentile of `update` in us."""
    return summarise(timed_run(estimator, samples)[1])
