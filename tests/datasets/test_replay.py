"""Replay: the recorded estimator with the recorded config reproduces the recorded estimates bit
for bit and scores like the live run; another estimator gets a dataset of its own."""

from __future__ import annotations

import numpy as np

from datasets.reader import read_recording
from datasets.replay import replay
from datasets.scoring import ScoringTruth, score_run
from estimators.scoring import METRIC_KEYS
from tests.datasets.conftest import run_rerun
from tests.datasets.test_roundtrip import assert_same_estimate


def live_truth(ticks) -> ScoringTruth:
    """What the live run scores with: the truth of every tick, straight from the ticks."""
    return ScoringTruth(np.array([t.truth.t for t in ticks]), np.array([t.truth_quaternion for t in ticks]),
                        np.array([t.truth.body_position for t in ticks]),
                        np.array([t.truth.foot_positions for t in ticks]),
                        np.array([t.truth.foot_contact for t in ticks]))


def test_replaying_the_recorded_estimator_reproduces_its_estimates_and_metrics(ekf_run):
    config, ticks, path = ekf_run
    live_estimates = [estimate for tick in ticks for estimate in tick.estimates]
    result = replay(path, "ekf")
    assert len(result.estimates) == len(live_estimates)
    for replayed, live in zip(result.estimates, live_estimates):
        assert_same_estimate(replayed, live)
    live_metrics = score_run(config, live_truth(ticks), live_estimates)
    assert live_metrics["roll_rmse_deg"] is not None and live_metrics["slope_error_deg"] is not None
    for key in METRIC_KEYS:
        assert result.metrics[key] == live_metrics[key], key
    assert result.truncation_note is None


def test_replay_through_another_estimator_writes_a_dataset_that_replays_itself(ekf_run, tmp_path):
    _, _, path = ekf_run
    out = tmp_path / "mahony.mcap"
    result = replay(path, "mahony", out=out)
    assert result.metrics["estimator"] == "mahony" and result.metrics["roll_rmse_deg"] is not None
    replayed = read_recording(out)
    assert replayed.run_info()["estimator"] == "mahony" and replayed.config().run.estimator == "mahony"
    assert len(replayed.estimates()) == len(result.estimates)
    original = read_recording(path)
    assert len(replayed.samples()) == len(original.samples())
    again = replay(out, "mahony")
    for a, b in zip(again.estimates, result.estimates):
        assert_same_estimate(a, b)
    assert {k: again.metrics[k] for k in METRIC_KEYS} == {k: result.metrics[k] for k in METRIC_KEYS}
    check = run_rerun("mcap", "check", str(out))
    assert check.returncode == 0, check.stdout + check.stderr


def test_replay_reports_its_speed(ekf_run):
    _, _, path = ekf_run
    metrics = replay(path, "complementary").metrics
    assert metrics["sim_time_s"] == 2.0 and metrics["samples"] > 10000
    assert metrics["realtime_factor"] == metrics["sim_time_s"] / metrics["wall_s"]
