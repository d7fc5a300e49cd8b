"""Offline replay: the recorded sensor streams through any estimator, scored against the recorded
truth with the live run's scoring.

The estimator is built by `estimators.registry.make_estimator` from the recorded config, and
receives the recorded samples of its `sample_types` (the replay reads only their topics) in the
order the run loop gave them to the live estimator; the live estimator of the same name and
config therefore produces bit-identical estimates again.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from datasets import codec, schemas
from datasets.background import exchanged_in_background
from datasets.reader import Recording, SampleBlock, read_recording, replay_inputs
from datasets.recorder import DatasetWriter
from datasets.scoring import ScoringTruth, score_as_they_come
from estimators.base import Estimate, Estimates, estimate_batches
from estimators.scoring import EstimateArrays, estimate_arrays
from estimators.registry import make_estimator, resolve_estimator
from sensors.samples import Sample
from testbed.runtime.config import Config
from testbed.runtime.garbage import older_objects_left_alone

NEEDED_TOPICS = (schemas.IMU.name, schemas.TRUTH_POSE.name, schemas.TRUTH_FEET.name)
EVERY_SENSOR_TOPIC = frozenset({schemas.SENSOR_PREFIX})
SAMPLES_PER_BLOCK = 4096


@dataclass(frozen=True)
class ReplayResult:
    metrics: dict
    estimates: Sequence[Estimate]    # `Estimates`: each Estimate object is built when first read
    samples: int
    truncation_note: str | None      # set when the file was truncated and only its readable part replayed


def replay(path: str | Path, estimator_name: str, out: str | Path | None = None,
           feed: Callable[[Iterable[Sample], float], Iterable[Sample]] | None = None) -> ReplayResult:
    """Replay `path` through `estimator_name`; with `out`, also write the run with the new
    estimates as a dataset of its own. `feed(samples, span_s)` gives the samples to the estimator
    in their order (`datasets.progress.with_progress` shows a progress bar over their span
    meanwhile).

    A forked process reads the file beside the estimator: it decodes the samples block by block,
    ahead of the estimator, then the truth, and scores the estimates as they come back to it."""
    started = time.perf_counter()
    recording = read_recording(path, topics=None if out is not None else ())
    config = recording.config().replace(run={"estimator": estimator_name})
    recording.require(*NEEDED_TOPICS, purpose=f"a replay through '{estimator_name}'")
    counted, feed = SampleCount(), feed or without_progress
    with older_objects_left_alone(), exchanged_in_background(read_and_score, path, sample_topics(estimator_name),
                                                             config) as (items, to_scorer):
        estimator = make_estimator(estimator_name, config)      # (while the file is read)
        inputs = ReplayInputs(items)
        estimates = Estimates()
        for batch in estimate_batches(estimator, feed(counted.samples(inputs.blocks()), sensor_span_s(recording))):
            if len(batch):
                estimates.add(batch)
                to_scorer.send(estimate_arrays(batch))     # (while the batch's columns are fresh in the caches)
        sim_time = inputs.sim_time()
        to_scorer.close()
        metrics = inputs.metrics()
    wall = time.perf_counter() - started
    metrics.update({"estimator": estimator_name, "samples": counted.count, "estimates": len(estimates),
                    "sim_time_s": sim_time, "wall_s": wall, "realtime_factor": sim_time / wall if wall > 0 else None})
    if out is not None:
        write_replayed(recording, Path(out), config, estimates, metrics)
    return ReplayResult(metrics, estimates, counted.count, recording.truncation_note())


def without_progress(samples: Iterable[Sample], span_s: float) -> Iterable[Sample]:
    return samples


@dataclass
class SampleCount:
    count: int = 0

    def samples(self, blocks: Iterable[SampleBlock]) -> Iterator[Sample]:
        """The samples of the blocks, counted as they pass."""
        for block in blocks:
            self.count += block.size
            yield from block.samples()


@dataclass(frozen=True)
class BlocksEnd:
    """After the last sample block."""
    sim_time: float         # s, from the first to the last truth step


def read_and_score(estimates: Iterator[EstimateArrays], path: str | Path, topics: frozenset[str],
                   config: Config) -> Iterator[SampleBlock | BlocksEnd | dict]:
    """The reading process of a replay: the blocks of samples of `topics` (`reader.replay_inputs`),
    BlocksEnd, then the metrics of the estimates the replay sends back in time-ordered parts, each
    scored against the truth as it comes."""
    truth = None
    for item in replay_inputs(path, topics, SAMPLES_PER_BLOCK):
        if isinstance(item, ScoringTruth):
            truth = item
        else:
            yield item
    yield BlocksEnd(float(truth.t[-1] - truth.t[0]) if len(truth.t) else 0.0)
    yield score_as_they_come(config, truth, estimates)


@dataclass
class ReplayInputs:
    """The items of `read_and_score`: sample blocks, BlocksEnd, the metrics."""
    items: Iterator[SampleBlock | BlocksEnd | dict]
    end: BlocksEnd | None = None

    def blocks(self) -> Iterator[SampleBlock]:
        for item in self.items:
            if isinstance(item, BlocksEnd):
                self.end = item
                return
            yield item

    def sim_time(self) -> float:
        """s, after the blocks (those not taken yet are skipped)."""
        if self.end is None:
            for _ in self.blocks():
                pass
        return self.end.sim_time

    def metrics(self) -> dict:
        """After `sim_time`, once the replay has sent every estimate."""
        return next(self.items)


def sensor_span_s(recording: Recording) -> float:
    """s from the first to the last sensor message of the file."""
    stats = [recording.topics[topic] for topic in recording.topics
             if topic.startswith(schemas.SENSOR_PREFIX) and recording.topics[topic].count]
    if not stats:
        return 0.0
    return (max(s.last_ns for s in stats) - min(s.first_ns for s in stats)) / codec.NS_PER_S


def sample_topics(estimator_spec: str) -> frozenset[str]:
    """The topics of the samples the estimator reads (`Estimator.sample_types`)."""
    types = resolve_estimator(estimator_spec).sample_types
    return EVERY_SENSOR_TOPIC if types is None else frozenset(codec.sample_topic(kind).name for kind in types)


def write_replayed(recording: Recording, out: Path, config: Config, estimates: Sequence[Estimate],
                   metrics: dict) -> None:
    """The recording with its estimates replaced by `estimates`, in log-time order."""
    messages = [(log_ns, sequence, topic, data) for topic, entries in recording.messages.items()
                if topic != schemas.ESTIMATE.name for log_ns, sequence, data in entries]
    encoder = codec.Encoder()
    messages += [(codec.to_ns(e.t), 0, schemas.ESTIMATE.name, encoder.estimate(e)) for e in estimates]
    messages.sort(key=lambda message: message[0])
    run_info = {**recording.run_info(), "estimator": config.run.estimator, "replayed_from": str(recording.path)}
    run_info.pop("format_version", None)
    dataset = DatasetWriter(out)
    try:
        dataset.describe_run(run_info, config, recording.urdf() or "")
        dataset.write([(dataset.channels[topic], log_ns, data, sequence)
                       for log_ns, sequence, topic, data in messages if topic in dataset.channels], flush=False)
        dataset.close(metrics, recording.outcome())
    except BaseException:
        if not dataset.closed:
            dataset.abandon()
        raise
