"""Replay: the recorded estimator with the recorded config reproduces the recorded estimates bit
for bit and scores like the live run; another estimator gets a dataset of its own."""

from __future__ import annotations

import gc
import json
import struct
import weakref

import numpy as np
import pytest
from mcap.reader import make_reader

from datasets import codec, schemas
from datasets import reader
from datasets.reader import SCORING_TOPICS, SampleBlock, read_recording, replay_inputs
from datasets.replay import replay, sample_topics
from datasets.scoring import ScoringTruth, score_as_they_come, score_run
from estimators.registry import make_estimator
from estimators.scoring import METRIC_KEYS, estimate_arrays
from sensors.samples import ImuSample
from tests.datasets.conftest import run_rerun
from testbed.model.errors import UserError
from testbed.runtime.garbage import older_objects_left_alone
from tests.datasets.test_roundtrip import assert_same_estimate, assert_same_sample

EVERY_SENSOR = frozenset({schemas.SENSOR_PREFIX})


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


@pytest.mark.parametrize("name", ["vqf", "madgwick"])
def test_an_imu_only_estimator_replays_from_the_imu_topic_to_its_per_sample_estimates(ekf_run, name):
    """Replay reads only the topics of `sample_types` and runs `update_batch` (VQF: the library's
    compiled loop), which must give what `update` gives sample by sample: the NaN accelerometer
    readings of the recorded dropout included."""
    config, ticks, path = ekf_run
    config = config.replace(run={"estimator": name})
    estimator = make_estimator(name, config)
    per_sample = [e for s in (s for tick in ticks for s in tick.samples) if (e := estimator.update(s)) is not None]
    result = replay(path, name)
    assert sample_topics(name) == {schemas.IMU.name}
    assert result.samples == sum(isinstance(s, ImuSample) for tick in ticks for s in tick.samples)
    assert len(result.estimates) == len(per_sample) > 1900
    for replayed, live in zip(result.estimates, per_sample):
        assert replayed.t == live.t
        np.testing.assert_allclose(replayed.quaternion, live.quaternion, rtol=0, atol=1e-12)
        np.testing.assert_allclose([replayed.roll, replayed.pitch], [live.roll, live.pitch], rtol=0, atol=1e-12)
        if live.gyro_bias is not None:
            np.testing.assert_allclose(replayed.gyro_bias, live.gyro_bias, rtol=0, atol=1e-15)
            np.testing.assert_allclose(replayed.gyro_bias_cov, live.gyro_bias_cov, rtol=1e-12, atol=0)


def test_a_replay_written_to_a_file_gives_the_estimator_only_its_sample_types(ekf_run, tmp_path):
    """With --out every topic is read; the IMU-only estimator must still get the IMU samples alone."""
    _, _, path = ekf_run
    read_only_imu, read_everything = replay(path, "vqf"), replay(path, "vqf", out=tmp_path / "vqf.mcap")
    assert len(read_everything.estimates) == len(read_only_imu.estimates) > 1900
    assert all(a.t == b.t and np.array_equal(a.quaternion, b.quaternion)
               for a, b in zip(read_everything.estimates, read_only_imu.estimates))


def test_vqf_batch_of_fewer_samples_than_it_needs_to_start_gives_no_estimate(ekf_run):
    config, ticks, _ = ekf_run
    first_imu = next(s for tick in ticks for s in tick.samples if isinstance(s, ImuSample))
    assert make_estimator("vqf", config.replace(run={"estimator": "vqf"})).update_batch([first_imu]) == []


@pytest.mark.parametrize("block_size", [1, 777, None])
def test_sample_blocks_of_any_size_give_the_samples_in_handing_order(ekf_run, block_size):
    """Against each message decoded on its own (`codec.decode_sample`), ordered by log time, then
    sequence (the recorder's numbering is in time order: ordered by sequence alone, the same)."""
    _, _, path = ekf_run
    recording = read_recording(path, topics=frozenset({schemas.SENSOR_PREFIX}))
    entries = sorted((log_ns, sequence, topic, data) for topic in schemas.SENSOR_TOPICS
                     for log_ns, sequence, data in recording.messages.get(topic, []))
    assert [sequence for _, sequence, _, _ in entries] == sorted(sequence for _, sequence, _, _ in entries)
    expected = [codec.decode_sample(topic, data) for _, _, topic, data in entries]
    blocks = list(recording.sample_blocks(block_size))
    assert [block.size for block in blocks][:-1] == [block_size or len(expected)] * (len(blocks) - 1)
    streamed = [sample for block in blocks for sample in block.samples()]
    assert len(streamed) == len(expected) > 2000 and len({type(sample) for sample in expected}) >= 3
    for a, b in zip(streamed, expected):
        assert type(a) is type(b)
        for x, y in zip(vars(a).values(), vars(b).values()):
            np.testing.assert_array_equal(x, y)         # NaN where NaN


def _with_recorded_config(recording, change):
    config = json.loads(recording.metadata["config"]["json"])
    change(config)
    recording.metadata["config"]["json"] = json.dumps(config)
    return recording


def test_a_recorded_config_without_a_newer_key_takes_its_default(ekf_run):
    _, _, path = ekf_run
    recording = read_recording(path, topics=())
    expected = recording.config()
    older = _with_recorded_config(read_recording(path, topics=()),
                                  lambda config: (config["terrain"].pop("course_start"), config["posture"].pop("max_swing_height")))
    assert older.config() == expected       # (the recorded values were the defaults)
    newer = _with_recorded_config(read_recording(path, topics=()), lambda config: config["terrain"].update(bumps=1.0))
    with pytest.raises(UserError, match="does not fit this testbed version.*unknown config key 'terrain.bumps'"):
        newer.config()


def streamed(path, topics=EVERY_SENSOR, block_size=500) -> tuple[list, ScoringTruth]:
    items = list(replay_inputs(path, topics, block_size))
    assert isinstance(items[-1], ScoringTruth) and all(isinstance(item, SampleBlock) for item in items[:-1])
    assert all(block.size == block_size for block in items[:-2])
    return [sample for block in items[:-1] for sample in block.samples()], items[-1]


def assert_same_samples(a, b):
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert_same_sample(x, y)


def assert_same_truth(a: ScoringTruth, b: ScoringTruth):
    for name in ("t", "quaternion", "body_position", "foot_positions", "foot_contact"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_the_replay_inputs_are_the_recordings_samples_then_its_truth(ekf_run, tmp_path):
    """Streamed chunk by chunk: the file as recorded, a replay's file (written in log-time order, the
    samples of one time in topic order) and a file without its summary (read whole first)."""
    _, _, path = ekf_run
    samples, truth = streamed(path)
    assert_same_samples(samples, read_recording(path).samples())
    assert_same_truth(truth, read_recording(path, SCORING_TOPICS).scoring_truth())
    replayed = tmp_path / "replayed.mcap"
    replay(path, "complementary", out=replayed)
    assert_same_samples(streamed(replayed)[0], samples)
    data = path.read_bytes()
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 4 - 8 - 8)    # the footer's
    without_summary = tmp_path / "no_summary.mcap"
    without_summary.write_bytes(data[:summary_start])
    no_summary_samples, no_summary_truth = streamed(without_summary)
    assert_same_samples(no_summary_samples, samples)
    assert_same_truth(no_summary_truth, truth)
    imu_only, _ = streamed(path, {schemas.IMU.name})
    assert_same_samples(imu_only, [sample for sample in samples if isinstance(sample, ImuSample)])


def test_the_first_block_is_handed_over_after_the_chunks_that_hold_it(ekf_run, monkeypatch):
    _, _, path = ekf_run
    with path.open("rb") as stream:
        chunks = len(make_reader(stream).get_summary().chunk_indexes)
    read = []
    take_chunk = reader._take_chunk
    monkeypatch.setattr(reader, "_take_chunk", lambda *args: (read.append(1), take_chunk(*args)))
    first = next(replay_inputs(path, EVERY_SENSOR, 100))
    assert first.size == 100 and chunks > 4 and len(read) <= 2


class Cycle:
    def __init__(self):
        self.me = self


def test_the_collector_leaves_older_objects_alone_during_a_replay_and_still_collects_its_garbage():
    gc.collect()
    with older_objects_left_alone():
        frozen = gc.get_freeze_count()
        cycle = weakref.ref(Cycle())
        gc.collect()
        assert frozen > 1000 and cycle() is None
    assert gc.get_freeze_count() == 0
    gc.freeze()                 # frozen by the program: left as it is
    try:
        before = gc.get_freeze_count()
        with older_objects_left_alone():
            pass
        assert gc.get_freeze_count() == before
    finally:
        gc.unfreeze()


@pytest.mark.parametrize("part", [1, 333, 10**6])
def test_estimates_scored_as_they_come_score_as_all_at_once(ekf_run, part):
    config, ticks, path = ekf_run
    estimates = [estimate for tick in ticks for estimate in tick.estimates]
    truth = read_recording(path, SCORING_TOPICS).scoring_truth()
    parts = (estimate_arrays(estimates[first:first + part]) for first in range(0, len(estimates), part))
    whole = score_run(config, truth, estimates)
    assert whole["roll_rmse_deg"] is not None and whole["position_rmse_m"] is not None
    assert score_as_they_come(config, truth, parts) == whole
