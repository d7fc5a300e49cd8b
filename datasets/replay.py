"""Offline replay: the recorded sensor streams through any estimator, scored against the recorded
truth with the live run's scoring.

The estimator is built by `estimators.registry.make_estimator` from the recorded config, and
receives the recorded samples of its `sample_types` (the replay reads only their topics) in the
order the run loop gave them to the live estimator; the live estimator of the same name and
config therefore produces bit-identical estimates again.
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from datasets import codec, schemas
from datasets.reader import Recording, read_recording
from datasets.recorder import DatasetWriter
from datasets.scoring import ScoringTruth, score_run
from estimators.base import Estimate, run_estimator
from estimators.registry import make_estimator, resolve_estimator
from sensors.samples import Sample
from testbed.runtime.config import Config

NEEDED_TOPICS = (schemas.IMU.name, schemas.TRUTH_POSE.name, schemas.TRUTH_FEET.name)
EVERY_SENSOR_TOPIC = frozenset({schemas.SENSOR_PREFIX})
SCORING_TOPICS = frozenset({schemas.TRUTH_POSE.name, schemas.TRUTH_FEET.name})
T = TypeVar("T")


@dataclass(frozen=True)
class ReplayResult:
    metrics: dict
    estimates: list[Estimate]
    samples: int
    truncation_note: str | None      # set when the file was truncated and only its readable part replayed


def replay(path: str | Path, estimator_name: str, out: str | Path | None = None,
           feed: Callable[[list[Sample]], Iterable[Sample]] = iter) -> ReplayResult:
    """Replay `path` through `estimator_name`; with `out`, also write the run with the new
    estimates as a dataset of its own. `feed` gives the samples to the estimator in their order
    (`datasets.progress.with_progress` shows a progress bar meanwhile)."""
    started = time.perf_counter()
    with in_background(read_scoring_truth, path) as scoring_truth:
        recording = read_recording(path, topics=None if out is not None else sample_topics(estimator_name))
        config = recording.config().replace(run={"estimator": estimator_name})
        recording.require(*NEEDED_TOPICS, purpose=f"a replay through '{estimator_name}'")
        estimator = make_estimator(estimator_name, config)
        samples = recording.samples()
        estimates = run_estimator(estimator, feed(samples))
        truth = scoring_truth()
    metrics = score_run(config, truth, estimates)
    sim_time = float(truth.t[-1] - truth.t[0]) if len(truth.t) else 0.0
    wall = time.perf_counter() - started
    metrics.update({"estimator": estimator_name, "samples": len(samples), "estimates": len(estimates),
                    "sim_time_s": sim_time, "wall_s": wall, "realtime_factor": sim_time / wall if wall > 0 else None})
    if out is not None:
        write_replayed(recording, Path(out), config, estimates, metrics)
    return ReplayResult(metrics, estimates, len(samples), recording.truncation_note())


def sample_topics(estimator_spec: str) -> frozenset[str]:
    """The topics of the samples the estimator reads (`Estimator.sample_types`)."""
    types = resolve_estimator(estimator_spec).sample_types
    return EVERY_SENSOR_TOPIC if types is None else frozenset(codec.sample_topic(kind).name for kind in types)


def read_scoring_truth(path: str | Path) -> ScoringTruth:
    return read_recording(path, topics=SCORING_TOPICS).scoring_truth()


@contextmanager
def in_background(function: Callable[..., T], *args: Any) -> Iterator[Callable[[], T]]:
    """`function(*args)` computed in a forked process on another core while the caller goes on;
    yields the call that waits for its value (or raises its exception). Computed inline where
    processes cannot be forked. The process ignores SIGINT: the caller handles an interruption."""
    if "fork" not in multiprocessing.get_all_start_methods():
        value = function(*args)
        yield lambda: value
        return
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                             initializer=signal.signal, initargs=(signal.SIGINT, signal.SIG_IGN)) as pool:
        yield pool.submit(function, *args).result


def write_replayed(recording: Recording, out: Path, config: Config, estimates: list[Estimate], metrics: dict) -> None:
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
