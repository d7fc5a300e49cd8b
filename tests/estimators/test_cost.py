import numpy as np

from estimators.base import run_estimator
from estimators.cost import per_simulated_ms, summarise, timed_run, update_costs
from estimators.registry import make_estimator


def test_update_costs_per_sample_type(runs):
    samples = [s for s in runs.samples(0) if s.t < 1.0]
    costs = update_costs(make_estimator("ekf", runs.config), samples)
    assert set(costs) == {"ImuSample", "EncoderSample", "FootSample"}
    assert costs["ImuSample"]["count"] == sum(type(s).__name__ == "ImuSample" for s in samples)
    for cost in costs.values():
        assert 0 < cost["median_us"] <= cost["p99_us"]
    # A regression guard, far above the ~8 us measured: a scipy Rotation in the hot path or a
    # covariance propagated at every IMU sample again would cross it.
    assert costs["ImuSample"]["median_us"] < 60


def test_timed_run_gives_the_estimates_of_a_plain_run(runs):
    samples = [s for s in runs.samples(1) if s.t < 0.5]
    timed, elapsed = timed_run(make_estimator("ekf", runs.config), samples)
    plain = run_estimator(make_estimator("ekf", runs.config), samples)
    assert len(timed) == len(plain) and all(np.array_equal(a.quaternion, b.quaternion) for a, b in zip(timed, plain))
    costs = summarise(elapsed)
    expected = sum(c["median_us"] * c["count"] for c in costs.values()) / 500.0
    assert per_simulated_ms(costs, 0.5) == expected
    # Guard far above the ~25 us per simulated ms measured (docs/estimators.md).
    assert per_simulated_ms(costs, 0.5) < 150
