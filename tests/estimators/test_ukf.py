import numpy as np
import pytest

from testbed.model import spatial as rot
from estimators.base import run_estimator
from estimators.ekf import predict
from estimators.fusion import ACCEL_BIAS, BIAS, ERROR_DIM, NominalState, apply_preintegration, current_pose, inject
from estimators.preintegration import Preintegration
from estimators.registry import make_estimator
from estimators.ukf import UkfEstimator, corrected, difference, propagate_errors
from tests.estimators.helpers import all_finite

GRAVITY = 9.81


def random_interval(seed: int) -> tuple[NominalState, Preintegration]:
    """A nominal state and five IMU samples of a shaking, turning body after it."""
    rng = np.random.default_rng(seed)
    state = NominalState(rot.quaternion_from_euler(0.1, -0.2, 0.3), rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3),
                         rng.normal(0, 0.05, 3), rng.normal(0, 0.1, (6, 3)), rng.normal(0, 1e-3, 2),
                         rng.normal(0, 1.0, 3))
    pre = Preintegration(GRAVITY)
    pre.start(state.q, state.bias, state.accel_bias)
    for _ in range(5):
        pre.add(rng.normal(0, 0.5, 3), np.array([0.0, 0.0, GRAVITY]) + rng.normal(0, 3, 3), 1e-3)
    return state, pre


def test_preintegration_matches_step_by_step_integration():
    rate, accel, dt = np.array([0.3, -0.2, 0.5]), np.array([0.5, -1.0, 9.8]), 1e-3
    pre = Preintegration()
    R, v, p = np.eye(3), np.zeros(3), np.zeros(3)
    for _ in range(4):
        pre.add(rate, accel, dt)
        p, v = p + v * dt + 0.5 * R @ accel * dt**2, v + R @ accel * dt
        R = R @ rot.to_matrix(rot.exp(*(rate * dt)))
    assert np.allclose(rot.to_matrix(tuple(pre.dq)), R, atol=1e-15)
    assert np.allclose(pre.dv, v, atol=1e-15) and np.allclose(pre.dp, p, atol=1e-15)
    assert pre.dt == pytest.approx(4 * dt)


def test_ekf_transition_is_the_jacobian_of_the_process_model():
    """F of the EKF against central differences of fusion.apply_preintegration (bias errors enter
    through the preintegration's bias Jacobians, as the UKF's sigma points do)."""
    state, pre = random_interval(3)
    after, _ = apply_preintegration(state, pre, GRAVITY)
    velocity, feet, position, F = state.velocity.copy(), state.feet.copy(), state.position.copy(), np.eye(ERROR_DIM)
    q = predict(pre.record, velocity, feet, position, np.eye(ERROR_DIM), F, np.zeros(ERROR_DIM), np.zeros(ERROR_DIM))
    assert np.allclose(q, after.q, atol=1e-15) and np.allclose(velocity, after.velocity, atol=1e-15)
    assert np.allclose(feet, after.feet, atol=1e-15) and np.allclose(position, after.position, atol=1e-15)
    numeric = np.zeros_like(F)
    for i in range(ERROR_DIM):
        dx = np.zeros(ERROR_DIM)
        dx[i] = 1e-6
        moved = [apply_preintegration(inject(state, sign * dx), corrected(pre, sign * dx[BIAS], sign * dx[ACCEL_BIAS]),
                                      GRAVITY)[0] for sign in (1, -1)]
        numeric[:, i] = (difference(moved[0], after) - difference(moved[1], after)) / 2e-6
    assert np.abs(numeric - F).max() < 1e-8
    assert np.abs(F - np.eye(ERROR_DIM)).max() > 1e-3     # not trivially the identity


def test_batched_process_model_equals_the_per_point_one():
    state, pre = random_interval(1)
    after, _ = apply_preintegration(state, pre, GRAVITY)
    sigmas = np.random.default_rng(2).normal(0, 0.05, (2 * ERROR_DIM + 1, ERROR_DIM))
    batched = propagate_errors(sigmas, state, after, pre, GRAVITY)
    one_by_one = np.array([UkfEstimator._fx(s, pre.dt, state, after, pre, GRAVITY) for s in sigmas])
    assert np.allclose(batched, one_by_one, atol=1e-14)


@pytest.mark.slow
def test_ukf_agrees_with_the_ekf(runs):
    samples = [s for s in runs.samples(0) if s.t < 2.0]
    ukf = run_estimator(make_estimator("ukf", runs.config), samples)
    ekf = run_estimator(make_estimator("ekf", runs.config), samples)
    assert all_finite(ukf) and len(ukf) == len(ekf)
    later = slice(1000, None)
    difference_deg = np.degrees([[u.roll - e.roll, u.pitch - e.pitch] for u, e in zip(ukf[later], ekf[later])])
    assert np.abs(difference_deg).max() < 0.03
    ratio = np.sqrt([u.attitude_cov[0, 0] / e.attitude_cov[0, 0] for u, e in zip(ukf[later], ekf[later])])
    assert 0.7 < ratio.min() and ratio.max() < 1.4
    assert ukf[-1].body_height == pytest.approx(ekf[-1].body_height, abs=5e-4)


def test_current_pose_is_the_preintegrated_state_at_the_body_origin():
    """fusion.current_pose against apply_preintegration: o = r - R l, v_o = R (v - w x l)."""
    state, pre = random_interval(4)
    after, _ = apply_preintegration(state, pre, GRAVITY)
    lever = np.array([0.01, -0.02, 0.03])
    rate = pre.record[0]["last_gyro"] - pre.record[0]["gyro_bias"]
    position, velocity = current_pose(pre.record, state.position, state.velocity, lever)
    R = rot.to_matrix(after.q)
    np.testing.assert_allclose(position, after.position - R @ lever, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(velocity, R @ (after.velocity - np.cross(rate, lever)), rtol=1e-12, atol=1e-14)
