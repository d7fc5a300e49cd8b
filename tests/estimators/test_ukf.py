import math

import numpy as np
import pytest

from estimators import rotations as rot
from estimators.base import run_estimator
from estimators.fusion import ERROR_DIM, NominalState, propagate
from estimators.registry import make_estimator
from estimators.ukf import UkfEstimator, propagate_errors
from tests.estimators.helpers import all_finite


def test_batched_process_model_equals_the_per_point_one():
    rng = np.random.default_rng(1)
    before = NominalState(rot.quaternion_from_euler(0.1, -0.2, 0.3), rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3),
                          rng.normal(0, 1, 3), rng.normal(0, 0.1, 3), rng.normal(0, 0.1, (6, 3)))
    gyro, dt = rng.normal(0, 0.5, 3), 1e-3
    decay = math.exp(-dt / 0.1)
    after, _ = propagate(before, gyro, dt, decay)
    sigmas = rng.normal(0, 0.05, (2 * ERROR_DIM + 1, ERROR_DIM))
    batched = propagate_errors(sigmas, dt, before, after, gyro, decay)
    one_by_one = np.array([UkfEstimator._fx(s, dt, before, after, gyro, decay) for s in sigmas])
    assert np.allclose(batched, one_by_one, atol=1e-14)


@pytest.mark.slow
def test_ukf_agrees_with_the_ekf(runs):
    samples = [s for s in runs.samples(0) if s.t < 2.0]
    ukf_estimator = make_estimator("ukf", runs.config)
    ukf = run_estimator(ukf_estimator, samples)
    ekf = run_estimator(make_estimator("ekf", runs.config), samples)
    assert all_finite(ukf) and len(ukf) == len(ekf)
    later = slice(1000, None)
    difference = np.degrees([[u.roll - e.roll, u.pitch - e.pitch] for u, e in zip(ukf[later], ekf[later])])
    assert np.abs(difference).max() < 0.03
    ratio = np.sqrt([u.attitude_cov[0, 0] / e.attitude_cov[0, 0] for u, e in zip(ukf[later], ekf[later])])
    assert 0.7 < ratio.min() and ratio.max() < 1.4
    assert ukf[-1].body_height == pytest.approx(ekf[-1].body_height, abs=5e-4)
    assert ukf_estimator.rejected_accel == 0
