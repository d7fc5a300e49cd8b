"""The fusion filter's full body state (position, velocity, yaw) on the synthetic walk, the pose
metrics, and the recovery from gyro faults."""

import numpy as np
import pytest

from estimators.base import run_estimator
from estimators.registry import make_estimator
from estimators.scoring import POSE_KEYS, METRIC_KEYS, estimate_arrays, roll_pitch_yaw, score, truth_at
from sensors.samples import ImuSample
from tests.estimators.conftest import WALK_SEEDS

FAULT_START, FAULT_END = 2.5, 3.5     # s


def pose_metrics(estimates, walk) -> dict:
    return score(estimate_arrays(estimates), walk.t, walk.rotation, truth_position=walk.position)


def test_straight_walk_position_velocity_and_yaw(runs, walk):
    """0.30 m walked in 6 s (5 s scored): measured 0.04-0.05 % drift, 0.2-0.3 mm RMSE, 1.3-1.5 mm/s."""
    distance = float(np.linalg.norm(walk.position[-1, :2] - walk.position[0, :2]))
    assert distance > 0.25
    for seed in WALK_SEEDS:
        metrics = pose_metrics(runs.run("ekf", seed)[0], walk)
        assert metrics["position_drift_pct"] < 0.2, seed
        assert metrics["position_rmse_m"] < 0.001, seed
        assert metrics["velocity_rmse_mps"] < 0.003, seed
        assert metrics["yaw_error_final_deg"] < 0.1, seed
        assert 0.5 < metrics["anees_pose"] < 9.0, seed          # 2.4-4.0: the covariances are not too small


def test_estimates_carry_the_body_velocity(runs, walk):
    """The velocity is the body origin's at the estimate's time (not the last filter step's)."""
    estimates, _ = runs.run("ekf", 0)
    t = np.array([e.t for e in estimates])
    velocity = np.array([e.velocity for e in estimates])
    true_velocity = np.column_stack([np.interp(t, walk.t, np.gradient(walk.position[:, i], walk.t))
                                     for i in range(3)])
    late = t > 1.0
    assert np.abs(true_velocity[late, 0]).max() > 0.05          # the body walks and sways
    assert np.sqrt(np.mean(np.sum((velocity[late] - true_velocity[late])**2, axis=1))) < 0.003


@pytest.mark.parametrize("name", ["madgwick", "vqf"])
def test_attitude_only_estimators_have_no_pose_metrics(runs, walk, name):
    estimates, _ = runs.run(name, 0)
    assert estimates[-1].position is None and estimates[-1].velocity_cov is None
    metrics = pose_metrics(estimates, walk)
    assert set(metrics) == set(METRIC_KEYS)
    assert all(metrics[key] is None for key in POSE_KEYS)
    assert metrics["roll_rmse_deg"] is not None


def with_gyro_fault(samples, kind: str):
    """A 0.5 rad/s bias step on the x axis, or the gyro stuck at its last reading, for 1 s."""
    held, out = None, []
    for s in samples:
        if isinstance(s, ImuSample) and FAULT_START <= s.t < FAULT_END:
            if kind == "bias_step":
                s = ImuSample(s.t, s.accel, s.gyro + np.array([0.5, 0.0, 0.0]))
            else:
                held = s.gyro.copy() if held is None else held
                s = ImuSample(s.t, s.accel, held)
        out.append(s)
    return out


@pytest.mark.parametrize("kind", ["bias_step", "stuck"])
def test_the_filter_recovers_within_two_seconds_of_a_gyro_fault(runs, walk, config, kind):
    """A 1 s fault: detected (the stuck gyro within STUCK_GYRO_SAMPLES, the bias step at the end of
    a detection window), and back to the clean accuracy 2 s after the fault ends (measured: 0.02 to
    0.07 deg of error left)."""
    for seed in WALK_SEEDS[:2]:
        ekf = make_estimator("ekf", config)
        estimates = estimate_arrays(run_estimator(ekf, with_gyro_fault(runs.samples(seed), kind)))
        assert ekf.bias_steps.detections >= 1, seed
        true_rpy = roll_pitch_yaw(truth_at(estimates.t, walk.t, walk.rotation))
        error = np.column_stack([estimates.roll - true_rpy[:, 0], estimates.pitch - true_rpy[:, 1]])
        recovered = estimates.t >= FAULT_END + 2.0
        assert np.degrees(np.abs(error[recovered])).max() < 0.1, seed
