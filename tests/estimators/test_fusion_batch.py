"""The fusion filters' `update_batch` (a compiled loop over the IMU samples between encoder samples)
gives the estimates `update` gives one sample at a time: on a walk, through gyro and accelerometer
faults, encoder gaps, and on rough ground."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import testbed
from datasets.reader import REPLAY_TOPICS, read_recording
from estimators import fusion
from estimators.base import Estimate, run_estimator
from estimators.registry import make_estimator
from sensors.samples import EncoderSample, ImuSample


def assert_same_estimates(batch: list[Estimate], per_sample: list[Estimate]) -> None:
    assert len(batch) == len(per_sample) > 0
    for got, expected in zip(batch, per_sample):
        assert got.t == expected.t
        for field in dataclasses.fields(Estimate):
            a, b = getattr(got, field.name), getattr(expected, field.name)
            if b is None:
                assert a is None, (expected.t, field.name)
            else:
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, err_msg=f"{field.name} at {expected.t}")


def one_at_a_time(estimator, samples) -> list[Estimate]:
    return [estimate for estimate in map(estimator.update, samples) if estimate is not None]


def with_faults(samples: list, start: float) -> list:
    """From `start` on: the gyro stuck for 0.3 s, missing (NaN) and infinite readings, accelerometer
    spikes (rejected), then rejected for longer than the gate's recovery time (the tilt restarts),
    an encoder gap of 0.1 s (the filter steps on its own), a repeated timestamp, and readings as
    lists instead of arrays."""
    out, stuck = [], None
    for sample in samples:
        t = sample.t - start
        if isinstance(sample, ImuSample):
            if 0.0 <= t < 0.3:
                stuck = sample.gyro if stuck is None else stuck
                sample = dataclasses.replace(sample, gyro=stuck)
            elif 0.4 <= t < 0.41:
                sample = dataclasses.replace(sample, gyro=np.array([np.nan, 0.0, 0.0]))
            elif 0.45 <= t < 0.452:
                sample = dataclasses.replace(sample, accel=np.array([0.0, np.inf, 9.8]))
            elif 0.5 <= t < 0.51:
                sample = dataclasses.replace(sample, accel=np.full(3, np.nan))
            elif 0.6 <= t < 0.605 or 0.8 <= t < 1.5:
                sample = dataclasses.replace(sample, accel=sample.accel + 60.0)
            elif 2.0 <= t < 2.01:
                sample = dataclasses.replace(sample, gyro=list(sample.gyro), accel=list(sample.accel))
            elif 2.1 <= t < 2.101:
                out.append(sample)
                sample = dataclasses.replace(sample, gyro=sample.gyro + 1e-3)      # the same time again
        elif isinstance(sample, EncoderSample) and 1.7 <= t < 1.8:
            continue
        out.append(sample)
    return out


def assert_batches_match(name: str, config, samples: list, batches=(4096, 333)) -> None:
    """Batches of the replay's size and of an odd one give the per-sample estimates and counters."""
    reference = make_estimator(name, config)
    per_sample = one_at_a_time(reference, samples)
    for batch in batches:
        estimator = make_estimator(name, config)
        assert_same_estimates(run_estimator(estimator, samples, batch), per_sample)
        for counter in ("rejected_accel", "tilt_restarts", "velocity_restarts", "rejected_feet"):
            assert getattr(estimator, counter) == getattr(reference, counter), counter
        assert estimator.t == reference.t


def test_the_batch_runs_the_imu_samples_through_the_compiled_loop(runs, config, monkeypatch):
    calls = []

    def counted(*args):
        calls.append(len(args[1]))
        return imu_samples(*args)

    imu_samples = fusion.imu_samples
    monkeypatch.setattr(fusion, "imu_samples", counted)
    samples = runs.samples(0)
    make_estimator("ekf", config).update_batch(samples)
    imu = sum(type(sample) is ImuSample for sample in samples)
    # one call per encoder interval (200 Hz against the IMU's 1 kHz), taking nearly every sample
    assert 0 < len(calls) < imu / 4 and sum(calls) > 0.99 * imu


def first_seconds(samples: list, seconds: float) -> list:
    return [sample for sample in samples if sample.t < seconds]


@pytest.mark.parametrize("name, batches", [("ekf", (4096, 333)), ("ukf", (333,))])
def test_a_walk_through_faults_gives_the_per_sample_estimates(runs, config, name, batches):
    faulty = with_faults(first_seconds(runs.samples(1), 3.3), start=1.0)
    reference = make_estimator(name, config)
    one_at_a_time(reference, faulty)
    assert reference.rejected_accel > 500 and reference.tilt_restarts >= 1     # the faults took effect
    assert_batches_match(name, config, faulty, batches)


def test_a_clean_walk_gives_the_per_sample_estimates(runs, default_config):
    """With the defaults: rolling and sinking feet, the accelerometer offset learnt at start-up."""
    assert_batches_match("ekf", default_config, first_seconds(runs.samples(2), 3.0), (4096,))


@pytest.fixture(scope="module")
def rough_walk(tmp_path_factory):
    """(config, samples) of a 2.5 s DART run on rough ground."""
    path = tmp_path_factory.mktemp("rough") / "walk.mcap"
    testbed.run({"run": {"terrain": "rough", "gait": "tripod", "estimator": "ekf", "duration": 2.5, "seed": 3}},
                out=path)
    recording = read_recording(path, topics=REPLAY_TOPICS)
    return recording.config(), recording.samples()


@pytest.mark.slow
def test_a_rough_ground_walk_gives_the_per_sample_estimates(rough_walk):
    config, samples = rough_walk
    assert_batches_match("ekf", config, samples, (777,))
    assert_batches_match("ekf", config, with_faults(samples, start=0.5), (4096,))


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_a_missing_gyro_reading_widens_the_attitude_whether_array_or_list(runs, config, name):
    """A NaN gyro reading is missing in whatever container it comes: the filter integrates the
    unknown body rate into the attitude's variance, the same for a float64 array (the live run's
    and the replay's) as for a list."""
    samples = first_seconds(runs.samples(1), 3.0)
    start = 1.0

    def without_gyro(as_array: bool) -> list:
        reading = np.array([np.nan, 0.0, 0.0]) if as_array else [np.nan, 0.0, 0.0]
        return [dataclasses.replace(sample, gyro=reading)
                if isinstance(sample, ImuSample) and start <= sample.t < start + 0.5 else sample
                for sample in samples]

    clean = one_at_a_time(make_estimator(name, config), samples)
    as_array, as_list = (one_at_a_time(make_estimator(name, config), without_gyro(flag)) for flag in (True, False))
    assert_same_estimates(as_array, as_list)
    yaw_variance = [next(e for e in estimates if e.t >= start + 0.5).attitude_cov[2, 2]
                    for estimates in (clean, as_array)]
    assert yaw_variance[1] > 2 * yaw_variance[0]
