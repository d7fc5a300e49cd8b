"""The fusion filters' batch keeps the estimates of its compiled IMU loop as rows (`EstimateRows`
in `Estimates`): their Estimate objects, built when read, and their scoring columns, taken from the
rows, are those of `update` one sample at a time, through faults (stuck gyro, NaN readings,
rejected specific force, an encoder gap) and before the first support plane."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimators.base import Estimate, EstimateRows, Estimates, Estimator, estimate_batches, run_estimator
from estimators.registry import make_estimator
from estimators.scoring import EstimateArrays, estimate_arrays
from sensors.samples import ImuSample
from tests.estimators.test_fusion_batch import assert_same_estimates, first_seconds, one_at_a_time, with_faults


def assert_same_arrays(got: EstimateArrays, expected: EstimateArrays) -> None:
    for field in dataclasses.fields(EstimateArrays):
        a, b = getattr(got, field.name), getattr(expected, field.name)
        if b is None:
            assert a is None, field.name
        else:
            assert a.shape == b.shape, field.name
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, err_msg=field.name)
            assert np.array_equal(np.isnan(a), np.isnan(b)), field.name


@pytest.fixture(scope="module")
def faulty_walk(runs):
    return with_faults(first_seconds(runs.samples(3), 3.3), start=1.0)


@pytest.mark.parametrize("batch", [4096, 333])
def test_rows_give_the_per_sample_estimates_and_columns(faulty_walk, config, batch):
    per_sample = one_at_a_time(make_estimator("ekf", config), faulty_walk)
    batches = list(estimate_batches(make_estimator("ekf", config), faulty_walk, batch))
    rows = sum(len(part) for estimates in batches for part in estimates.parts if isinstance(part, EstimateRows))
    assert rows > 0.5 * len(per_sample)       # most estimates came from the compiled loop as rows
    columns = [estimate_arrays(estimates) for estimates in batches]      # before any object is built
    expected = estimate_arrays(per_sample)
    assert np.isnan(expected.terrain_roll[0]) and np.isfinite(expected.terrain_roll[-1])
    joined = Estimates()
    for estimates in batches:
        joined.add(estimates)
    assert_same_arrays(estimate_arrays(joined), expected)
    assert sum(len(c.t) for c in columns) == len(per_sample)
    np.testing.assert_array_equal(np.concatenate([c.roll for c in columns]), expected.roll)
    assert_same_estimates(list(joined), per_sample)
    for estimates in batches:
        assert_same_arrays(estimate_arrays(estimates.objects()), estimate_arrays(estimates))


def test_estimates_build_each_object_once_and_keep_their_order(faulty_walk, config):
    estimator = make_estimator("ekf", config)
    estimates = Estimates()
    chunks = [faulty_walk[:2000], faulty_walk[2000:5000], faulty_walk[5000:]]
    estimates.add(estimator.batch_estimates(chunks[0]))
    first = estimates[0]
    assert estimates[0] is first and next(iter(estimates)) is first
    estimates.add(estimator.batch_estimates(chunks[1]))     # after objects were built
    extra = Estimate(t=99.0, quaternion=np.array([0.0, 0.0, 0.0, 1.0]), roll=0.0, pitch=0.0, yaw=0.0)
    estimates.append(extra)
    estimates.add(estimator.batch_estimates(chunks[2]))
    times = [estimate.t for estimate in estimates]
    assert len(times) == len(estimates) and estimates[-1].t == times[-1]
    assert times.index(99.0) > 0 and estimates[times.index(99.0)] is extra
    expected = [e.t for e in one_at_a_time(make_estimator("ekf", config), faulty_walk)]
    assert times[:times.index(99.0)] + times[times.index(99.0) + 1:] == expected
    assert estimates == estimates.objects() and estimates != estimates.objects()[:-1]


class OnlyUpdate(Estimator):
    """A user's plugin: `update` alone, one estimate per finite gyro reading."""

    def update(self, sample):
        if isinstance(sample, ImuSample) and np.isfinite(sample.gyro).all():
            return Estimate(sample.t, np.array([0.0, 0.0, 0.0, 1.0]), float(sample.gyro[0]), 0.0, 0.0)
        return None


def test_an_estimator_with_only_update_batches_as_before(faulty_walk):
    expected = one_at_a_time(OnlyUpdate(), faulty_walk)
    batches = list(estimate_batches(OnlyUpdate(), faulty_walk, 333))
    assert all(isinstance(part, list) for estimates in batches for part in estimates.parts)
    joined = Estimates()
    for estimates in batches:
        joined.add(estimates)
    assert [e.roll for e in joined] == [e.roll for e in expected]
    assert_same_arrays(estimate_arrays(joined), estimate_arrays(expected))
    assert [e.t for e in run_estimator(OnlyUpdate(), faulty_walk)] == [e.t for e in expected]
