"""The EKF on the synthetic walk: accuracy against the baselines, consistency, bias, faults."""

import math
from dataclasses import replace

import numpy as np
import pytest

from estimators.base import run_estimator
from estimators.fusion import low_passed_loads
from estimators.registry import make_estimator
from estimators.scoring import anees_bounds, estimate_arrays, score
from sensors.samples import EncoderSample, ImuSample
from tests.estimators import synthetic
from tests.estimators.conftest import WALK_SEEDS
from tests.estimators.helpers import all_finite, metrics, tilt_errors_deg, tilt_rmse_deg

BASELINES = ("complementary", "madgwick", "mahony", "vqf")
ACCEL_FULL_SCALE = 58.84        # m/s^2, the default IMU's +-6 g range


def test_ekf_beats_every_baseline_on_every_seed(runs, walk):
    for seed in WALK_SEEDS:
        ekf = metrics(runs.run("ekf", seed)[0], walk)
        assert max(ekf["roll_rmse_deg"], ekf["pitch_rmse_deg"]) < 0.1
        assert ekf["tilt_error_max_deg"] < 0.3
        for name in BASELINES:
            baseline = metrics(runs.run(name, seed)[0], walk)
            assert ekf["roll_rmse_deg"] < baseline["roll_rmse_deg"], (name, seed)
            assert ekf["pitch_rmse_deg"] < baseline["pitch_rmse_deg"], (name, seed)


def test_ekf_tilt_covariance_is_consistent_over_seeds(runs, walk):
    anees = np.mean([metrics(runs.run("ekf", seed)[0], walk)["anees_tilt"] for seed in WALK_SEEDS])
    low, high = anees_bounds(len(WALK_SEEDS))
    assert low < anees < high


def test_ekf_converges_its_gyro_bias(runs, walk, spec):
    for seed in WALK_SEEDS[:2]:
        estimates, _ = runs.run("ekf", seed)
        _, _, true_bias = synthetic.imu_arrays(walk, spec, seed)
        final = estimates[-1]
        error = final.gyro_bias - true_bias                   # started from 0: 0.5 deg/s per axis off
        sigma = np.sqrt(np.diag(final.gyro_bias_cov))
        assert np.all(np.abs(error) < 3.5 * sigma)
        assert np.all(np.degrees(np.abs(error[:2])) < 0.03)  # the horizontal axes, seen through the tilt
        assert np.degrees(sigma[2]) < 0.5                     # the vertical one only as the body turns


def test_yaw_is_reported_as_unobserved(runs, walk):
    estimates, _ = runs.run("ekf", 0)
    yaw_sigma = np.sqrt([e.attitude_cov[2, 2] for e in estimates])
    roll_sigma = np.sqrt([e.attitude_cov[0, 0] for e in estimates])
    assert np.all(np.diff(yaw_sigma[1000::1000]) > 0)       # grows second after second...
    assert yaw_sigma[-1] > 10 * roll_sigma[-1]              # ...unlike roll
    # Yaw drifts within its reported variance, counted once the tilt has converged (the first
    # tilt corrections turn the heading by about the square of the initial tilt error).
    yaw_error = np.array([e.yaw for e in estimates]) - walk.roll_pitch_yaw[:, 2]
    drift = yaw_error[1000:] - yaw_error[1000]
    growth = np.sqrt(np.maximum(0.0, yaw_sigma[1000:]**2 - yaw_sigma[1000]**2))
    assert np.all(np.abs(drift) < 4 * growth + 1e-4)


def with_accel_hits(samples: list, hit, every: float = 0.5) -> tuple[list, int]:
    """The accelerometer reading of one IMU sample every `every` seconds from 2 s replaced by
    `hit(reading)`; and how many were."""
    out, count, next_hit = [], 0, 2.0
    for sample in samples:
        if isinstance(sample, ImuSample) and sample.t >= next_hit:
            sample = ImuSample(sample.t, hit(sample.accel), sample.gyro)
            count, next_hit = count + 1, next_hit + every
        out.append(sample)
    return out, count


def with_accel_spikes(samples: list) -> tuple[list, int]:
    """Full-scale spikes on every axis of the accelerometer."""
    return with_accel_hits(samples, lambda accel: np.clip(accel + ACCEL_FULL_SCALE, -ACCEL_FULL_SCALE,
                                                          ACCEL_FULL_SCALE))


def run_ekf(config, samples):
    estimator = make_estimator("ekf", config)
    return run_estimator(estimator, samples), estimator


@pytest.mark.parametrize("seed", WALK_SEEDS[:2])
def test_accelerometer_spikes_are_gated(runs, walk, config, seed):
    clean = tilt_rmse_deg(runs.run("ekf", seed)[0], walk)
    samples, spikes = with_accel_spikes(runs.samples(seed))
    estimates, ekf = run_ekf(config, samples)
    assert ekf.rejected_accel == spikes
    assert tilt_rmse_deg(estimates, walk) < 1.1 * clean


def with_landing_shocks(samples: list, shock: float = 45.0) -> list:
    """A body acceleration of `shock` m/s^2 along z_b: a tripod landing on DART contact reaches
    30-51 m/s^2 for a few ms."""
    return with_accel_hits(samples, lambda accel: accel + np.array([0.0, 0.0, shock]))[0]


def test_landing_shocks_are_integrated_as_motion(runs, config):
    _, clean = run_ekf(config, runs.samples(0))
    _, shaken = run_ekf(config, with_landing_shocks(runs.samples(0)))
    assert shaken.rejected_accel == clean.rejected_accel
    gated = config.replace(estimators={"ekf": {"spike_body_accel": 40.0}})
    _, held_out = run_ekf(gated, with_landing_shocks(runs.samples(0)))
    assert held_out.rejected_accel > clean.rejected_accel


def test_encoder_dropout_of_one_second(runs, walk, config):
    clean_estimates, _ = runs.run("ekf", 0)
    gap = [s for s in runs.samples(0) if not (isinstance(s, EncoderSample) and 3.0 <= s.t < 4.0)]
    estimates, _ = run_ekf(config, gap)
    assert all_finite(estimates)
    assert tilt_rmse_deg(estimates, walk) < 2 * tilt_rmse_deg(clean_estimates, walk)
    later = estimates[1000:]
    height_error = np.array([e.body_height for e in later]) - walk.body_height[1000:]
    assert np.sqrt(np.mean(height_error**2)) < 5e-3
    # Held through the gap, with a variance that grows to cover the body's bobbing.
    height_sigma = np.sqrt([e.terrain_cov[2, 2] for e in later])
    assert np.all(np.abs(height_error[2000:3000]) < 4 * height_sigma[2000:3000])
    assert height_sigma[2990] > 5 * height_sigma[1990]


def test_one_leg_reading_nan_for_one_second(runs, walk, config):
    clean = tilt_rmse_deg(runs.run("ekf", 1)[0], walk)

    def blank_leg_two(sample):
        if isinstance(sample, EncoderSample) and 3.0 <= sample.t < 4.0:
            positions = sample.positions.copy()
            positions[3:6] = np.nan
            return EncoderSample(sample.t, positions)
        return sample

    estimates, _ = run_ekf(config, [blank_leg_two(s) for s in runs.samples(1)])
    assert all_finite(estimates)
    assert tilt_rmse_deg(estimates, walk) < 1.5 * clean


def test_gyro_bias_step_is_absorbed(runs, walk, config, spec):
    step = math.radians(0.5)
    samples = [ImuSample(s.t, s.accel, s.gyro + (step if s.t >= 3.0 else 0.0)) if isinstance(s, ImuSample) else s
               for s in runs.samples(2)]
    estimates, ekf = run_ekf(config, samples)
    clean = tilt_rmse_deg(runs.run("ekf", 2)[0], walk)
    assert ekf.bias_steps.detections >= 1
    # The step costs 0.2 deg for the ~0.5 s until it is detected: 0.061 deg RMSE over the 6 s walk,
    # against 0.020 clean (with the still-window gravity updates of the standing start).
    assert tilt_rmse_deg(estimates, walk) < 3.5 * clean
    assert np.abs(tilt_errors_deg(estimates, walk)[-1000:]).max() < 0.1     # recovered
    _, _, true_bias = synthetic.imu_arrays(walk, spec, 2)
    assert np.degrees(np.abs(estimates[-1].gyro_bias[:2] - true_bias[:2] - step)).max() < 0.1


def test_no_nan_under_extreme_input(runs, walk, config):
    def disturb(sample):
        if not isinstance(sample, ImuSample) or not 2.0 <= sample.t < 2.4:
            return sample
        if sample.t < 2.3:
            return ImuSample(sample.t, np.zeros(3), sample.gyro)                      # free fall
        if sample.t < 2.305:
            return ImuSample(sample.t, sample.accel, np.full(3, 1e4))                  # huge rate
        if sample.t < 2.31:
            return ImuSample(sample.t, np.array([np.nan, 1.0, np.inf]), np.array([np.nan, 0.0, 0.0]))
        if sample.t < 2.4:
            return ImuSample(sample.t, np.full(3, 1e6), sample.gyro)                   # saturated, wrong
        return sample

    samples = [disturb(s) for s in runs.samples(3)]
    estimates, ekf = run_ekf(config, samples)
    assert len(estimates) == len(walk.t)      # unreadable gyro samples: the last rate is held
    assert all_finite(estimates)
    assert all(np.all(np.linalg.eigvalsh(e.attitude_cov) >= -1e-12) for e in estimates[::100])
    late = [e for e in estimates if e.t > 4.0]
    assert np.abs(tilt_errors_deg(late, walk)).max() < 1.0                       # and it recovers


def test_estimates_are_bit_identical_on_replay(runs):
    samples = [s for s in runs.samples(0) if s.t < 1.5]
    for name in ("ekf", "complementary", "madgwick", "mahony", "vqf"):
        first = run_estimator(make_estimator(name, runs.config), samples)
        second = run_estimator(make_estimator(name, runs.config), samples)
        assert len(first) == len(second)
        for a, b in zip(first, second):
            assert a.t == b.t and np.array_equal(a.quaternion, b.quaternion)
            for field in ("attitude_cov", "gyro_bias", "terrain_cov"):
                x, y = getattr(a, field), getattr(b, field)
                assert (x is None and y is None) or np.array_equal(x, y)
            assert (a.roll, a.pitch, a.yaw, a.body_height) == (b.roll, b.pitch, b.yaw, b.body_height)


def test_default_tuning_also_beats_the_baselines(default_config, runs, walk):
    for seed in WALK_SEEDS[:2]:
        ekf = tilt_rmse_deg(run_estimator(make_estimator("ekf", default_config), runs.samples(seed)), walk)
        for name in BASELINES:
            assert ekf < tilt_rmse_deg(runs.run(name, seed)[0], walk), (name, seed)


def test_accelerometer_offset_estimated_or_covered(config, walk, spec):
    """Offsets of the raw BMI088 (20 mg): estimated from the body's turns, the EKF beats VQF; as a
    consider state (the default), the covariance covers the tilt error they cause."""
    biased = replace(spec, accel_bias_std=0.196)
    estimated = config.replace(estimators={"ekf": {"accel_bias_initial_std": 0.2, "accel_bias_estimation": "always"}})
    considered = config.replace(estimators={"ekf": {"accel_bias_initial_std": 0.2}})
    anees = {"estimated": [], "considered": []}
    ekf_rmse, vqf_rmse = [], []
    for seed in WALK_SEEDS[:3]:
        samples = synthetic.samples(walk, biased, 10 + seed)
        for label, tuning in (("estimated", estimated), ("considered", considered)):
            estimates = run_estimator(make_estimator("ekf", tuning), samples)
            anees[label].append(score(estimate_arrays(estimates), walk.t, walk.rotation)["anees_tilt"])
            if label == "estimated":
                ekf_rmse.append(tilt_rmse_deg(estimates, walk))
        vqf_rmse.append(tilt_rmse_deg(run_estimator(make_estimator("vqf", config), samples), walk))
    low, high = anees_bounds(3)
    assert low < np.mean(anees["estimated"]) < high
    assert low < np.mean(anees["considered"]) < high
    assert np.mean(ekf_rmse) < np.mean(vqf_rmse)


FOOT_RATE = 250.0       # Hz, the foot sensors'


def summed_squared_changes(readings: np.ndarray, time_constant: float) -> tuple[float, np.ndarray]:
    """Run the readings (one row per foot sample) through `low_passed_loads`; the sum of the squared
    changes of the loads (what `sink_feet` turns into foot variance) and the last loads."""
    loads, total = np.full(readings.shape[1], np.nan), 0.0
    for row in readings:
        before = loads
        loads = low_passed_loads(loads, row, 1.0 / FOOT_RATE, time_constant)
        if np.all(np.isfinite(before)):
            total += float(np.sum((loads - before)**2))
    return total, loads


@pytest.mark.parametrize("seed", [0, 5])
def test_a_ringing_load_moves_the_feet_far_less_than_a_load_transfer(seed):
    rng = np.random.default_rng(seed)
    samples = int(2.0 * FOOT_RATE)
    ringing = 6.0 + rng.normal(0.0, 3.0, (samples, 1))          # a steady 6 N, 3 N from sample to sample
    transfer = np.clip(32.0 * (np.arange(samples) / FOOT_RATE - 0.5), 0.0, 8.0)[:, None]   # 0 -> 8 N in 250 ms
    raw_ringing, _ = summed_squared_changes(ringing, 0.0)
    smoothed_ringing, _ = summed_squared_changes(ringing, 0.05)
    raw_transfer, _ = summed_squared_changes(transfer, 0.0)
    smoothed_transfer, last = summed_squared_changes(transfer, 0.05)
    assert smoothed_ringing < raw_ringing / 100.0
    # The transfer keeps its whole change and most of its summed square: its slide is unchanged.
    np.testing.assert_allclose(last, [8.0], rtol=1e-6)
    assert 0.6 * raw_transfer < smoothed_transfer <= raw_transfer


def test_load_low_pass_keeps_a_missing_reading_and_takes_the_first():
    loads = low_passed_loads(np.full(2, np.nan), np.array([5.0, np.nan]), 0.004, 0.05)
    np.testing.assert_array_equal(np.isnan(loads), [False, True])
    assert loads[0] == 5.0
    after = low_passed_loads(np.array([5.0, 3.0]), np.array([np.nan, 4.0]), 0.004, 0.05)
    assert after[0] == 5.0
    np.testing.assert_allclose(after[1], 3.0 + (1.0 - math.exp(-0.004 / 0.05)), rtol=1e-12)
    np.testing.assert_array_equal(low_passed_loads(np.array([5.0, 3.0]), np.array([1.0, 2.0]), 0.004, 0.0), [1.0, 2.0])
