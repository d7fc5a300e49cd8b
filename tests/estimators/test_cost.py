from estimators.cost import update_costs
from estimators.registry import make_estimator


def test_update_costs_per_sample_type(runs):
    samples = [s for s in runs.samples(0) if s.t < 1.0]
    costs = update_costs(make_estimator("ekf", runs.config), samples)
    assert set(costs) == {"ImuSample", "EncoderSample", "FootSample"}
    for cost in costs.values():
        assert 0 < cost["median_us"] <= cost["p99_us"]
    # A regression guard, far above the ~60-90 us measured: a scipy Rotation in the hot path
    # or an O(n^3) blow-up would cross it.
    assert costs["ImuSample"]["median_us"] < 500
