"""`McapRecorder`: every stream of a run into one MCAP file (topics: docs/dataset.md).

- The file is written as `<path>.partial` and renamed to `<path>` when it is closed, so a file
  with the final name is always complete.
- `record` only keeps the tick (its arrays are new at every step, never modified afterwards);
  every `flush_period` of simulated time the pending ticks are serialised, all in one loop, and go
  to the writer, which closes a chunk and hands it to its writer thread (`datasets.mcap_batch`):
  that thread compresses it, writes it and flushes it to disk while the run goes on.
  A process killed outright therefore leaves a `.partial` file whose chunks are readable up to
  the last flush, less the one chunk that the writer thread may still have been writing
  (`datasets.reader` recovers them). A process whose main thread ends without `finish` (an
  exception) still writes every chunk handed over.
- Ctrl-C cannot land inside a write (`datasets.signals`); `finish`, which the run loop calls
  after an interrupt or a divergence too, writes what is pending, waits for the writer thread,
  and writes the metrics and the summary. An error of the writer thread (a full disk) is raised
  by the next flush or by `finish`.
- Sensor samples, estimates, the body pose and the feet (what scoring reads) are recorded at every
  occurrence; the heavy truth (state, contacts, support polygon) and the commands every
  `truth_every` physics steps.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from datetime import datetime, timezone
from functools import cache
from itertools import count
from importlib import metadata as package_metadata
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from mcap_protobuf.schema import build_file_descriptor_set

from datasets import batch_encode, codec, schemas
from datasets.mcap_batch import BatchWriter
from datasets.signals import sigint_deferred
from testbed.runtime.recording import Tick

if TYPE_CHECKING:
    from testbed.runtime.config import Config
    from testbed.world.terrain import Terrain

TRUTH_RATE = 200.0          # Hz, heavy truth (state, contacts, support polygon) and commands
PARTIAL_SUFFIX = ".partial"
FLUSH_PERIOD = 0.5          # s of simulated time per chunk
CHUNK_SIZE = 8 * 2**20      # bytes; chunks normally close at each flush, before reaching this
PROFILE = "hexapod-testbed"
VERSIONED_PACKAGES = ("hexapod-testbed", "numpy", "scipy", "dartpy", "filterpy", "control", "AHRS", "vqf",
                      "mcap", "mcap-protobuf-support", "foxglove-schemas-protobuf", "protobuf", "rerun-sdk")


class DatasetWriter:
    """An MCAP file of the dataset format: every topic registered, the run description first,
    written under a temporary name until `close`."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.partial_path = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial_path, "wb")
        self._writer = BatchWriter(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD, background=True)
        self._writer.start(profile=PROFILE, library=f"hexapod-testbed/{_version('hexapod-testbed')}")
        self.channels = {topic.name: self._register(topic) for topic in schemas.TOPICS}
        self.closed = False

    def describe_run(self, run_info: dict[str, str], config: "Config", urdf: str) -> None:
        """Metadata and attachments go before any message, so that even a truncated file can be
        replayed."""
        writer = self._writer
        writer.add_metadata("run", {"format_version": schemas.FORMAT_VERSION, **run_info})
        writer.add_metadata("config", {"json": json.dumps(config.to_dict(), sort_keys=True)})
        writer.add_metadata("versions", package_versions())
        created = time.time_ns()
        writer.add_attachment(created, 0, "config.toml", "application/toml", config.to_toml().encode())
        writer.add_attachment(created, 0, "robot.urdf", "application/xml", urdf.encode())

    def add(self, topic: str, log_ns: int, data: bytes, sequence: int = 0) -> None:
        self._writer.add_message(self.channels[topic], log_ns, data, log_ns, sequence)

    def add_many(self, messages: list[tuple[int, int, bytes, int]], flush: bool) -> None:
        """(channel id, log ns, data, sequence) messages; `flush` closes the chunk and hands it to
        the writer thread, which writes it and flushes the file."""
        with sigint_deferred():
            self._writer.add_messages(messages)
            if flush:
                self._writer.flush()

    def add_batch(self, batch: batch_encode.Batch, flush: bool) -> None:
        """Message records laid out by `batch_encode`; `flush` as in `add_many`."""
        with sigint_deferred():
            self._writer.add_records(*batch)
            if flush:
                self._writer.flush()

    def wait(self) -> None:
        """Return when every chunk handed to the writer thread is on disk (flushed)."""
        with sigint_deferred():
            self._writer.wait()

    def close(self, metrics: dict, outcome: dict[str, str]) -> None:
        """Write the metrics, the outcome and the summary, then give the file its final name."""
        if self.closed:
            return
        self.closed = True
        try:
            with sigint_deferred():
                self._writer.add_metadata("metrics", {"json": json.dumps(_json_safe(metrics), sort_keys=True)})
                self._writer.add_metadata("outcome", outcome)
                self._writer.finish()
                self._file.close()
                os.replace(self.partial_path, self.path)
        finally:
            if not self._file.closed:
                self._close_file()

    def abandon(self) -> None:
        """Close without a summary and delete the temporary file (nothing worth keeping was written)."""
        self.closed = True
        self._close_file()
        self.partial_path.unlink(missing_ok=True)

    def _close_file(self) -> None:
        """Close the file after an error: once the writer thread has written what it was given
        (its own error, if any, is not the one to tell)."""
        try:
            self._writer.stop()
        finally:
            self._file.close()

    def _register(self, topic: schemas.Topic) -> int:
        descriptor_set = build_file_descriptor_set(topic.message_class).SerializeToString()
        schema_id = self._writer.register_schema(topic.message_class.DESCRIPTOR.full_name, SchemaEncoding.Protobuf,
                                                 descriptor_set)
        return self._writer.register_channel(topic.name, MessageEncoding.Protobuf, schema_id)


class McapRecorder:
    """Implements `testbed.runtime.recording.Recorder`."""

    def __init__(self, path: str | Path, truth_rate: float = TRUTH_RATE, flush_period: float = FLUSH_PERIOD):
        self.path = Path(path)
        self.truth_rate = truth_rate
        self.flush_period = flush_period
        self.busy_s = 0.0               # wall time spent inside the recorder
        self._dataset: DatasetWriter | None = None
        self._encoder = codec.Encoder()
        self._channels: dict[str, int] = {}
        self._channel_of = np.zeros(0, np.int64)     # batch_encode's channel of each layout
        self._pending: list[tuple] = []          # recorded, not yet encoded and written: _Step's fields
        self._ticks = 0
        self._samples = 0
        self._every = 1
        self._next_flush_ns = 0
        self._last_t = 0.0

    @property
    def partial_path(self) -> Path:
        return self.path.with_name(self.path.name + PARTIAL_SUFFIX)

    # --- Recorder protocol --------------------------------------------------------------------

    def start(self, config: "Config", urdf: str, terrain: "Terrain") -> None:
        started = time.perf_counter()
        self._every = truth_every(config.run.time_step, self.truth_rate)
        self._dataset = DatasetWriter(self.path)
        self._channels = self._dataset.channels
        self._channel_of = batch_encode.channels_of(self._channels)
        self._dataset.describe_run(run_description(config, self._every, self.truth_rate), config, urdf)
        boxes = terrain.boxes
        terrain_data = codec.terrain_message(boxes.centers, boxes.half_extents, boxes.rotations, terrain.name)
        self._dataset.add_many([(self._channels[schemas.TERRAIN.name], 0, terrain_data, 0)], flush=True)
        self._next_flush_ns = codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def record(self, tick: Tick) -> None:
        started = time.perf_counter()
        truth = tick.truth
        t = truth.t
        ticks = self._ticks
        # a _Step, as a plain tuple (a third of the cost)
        self._pending.append((t, truth.body_position, tick.truth_quaternion, truth.foot_positions, truth.foot_contact,
                              tick.samples, tick.estimates, None if ticks % self._every else tick))
        self._ticks = ticks + 1
        self._last_t = t
        t_ns = codec.to_ns(t)
        if t_ns >= self._next_flush_ns:
            self._write_pending(flush=True)
            self._next_flush_ns = t_ns + codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def finish(self, metrics: dict, error: str | None) -> None:
        """Close the file validly and give it its final name. Safe to call more than once."""
        if self._dataset is None or self._dataset.closed:
            return
        started = time.perf_counter()
        try:
            self._write_pending(flush=False)
        finally:
            outcome = {"error": error or "", "ticks": str(self._ticks), "sim_time_s": repr(self._last_t),
                       "recording_wall_s": repr(self.busy_s + time.perf_counter() - started)}
            self._dataset.close(metrics, outcome)

    # --- internals ----------------------------------------------------------------------------

    def _write_pending(self, flush: bool) -> None:
        """Encode what was recorded since the last write (`batch_encode`'s compiled layout, or the
        Python encoder's messages) and write it. A Ctrl-C while encoding
        leaves it pending for `finish`; from the moment it is handed over to the writer it waits
        until it is written (the encoding holds numpy calls long enough for a signal to come due
        right after it)."""
        steps = self._pending
        batch = batch_encode.lay_out(steps, self._channel_of, self._samples)
        messages = self._messages([_Step._make(step) for step in steps]) if batch is None else None
        with sigint_deferred():
            self._samples += sum([len(step[_SAMPLES]) for step in steps])
            steps.clear()
            if batch is not None:
                self._dataset.add_batch(batch, flush)
            else:
                self._dataset.add_many(messages, flush)

    def _messages(self, steps: list[_Step]) -> list[tuple[int, int, bytes, int]]:
        """(channel, log ns, data, sequence) of the steps, step by step: the samples, the estimates,
        the pose, the feet and, where the step keeps its tick, the heavy truth. Each topic's
        messages are encoded in one batch (the encoder vectorises it), then laid out in that order.
        The Python encoder's path: for the values that `batch_encode` does not take, and its
        reference in tests/datasets/test_batch_encode.py."""
        channels, encoder = self._channels, self._encoder
        samples = [sample for step in steps for sample in step.samples]
        estimates = [estimate for step in steps for estimate in step.estimates]
        truth_ns = codec.to_ns_many([step.t for step in steps])
        sample_messages = [(channels[topic], t_ns, data, sequence) for (topic, data), t_ns, sequence in zip(
            encoder.samples(samples), codec.to_ns_many([sample.t for sample in samples]), count(self._samples))]
        estimate_channel, pose_channel, feet_channel = (channels[topic.name] for topic in
                                                        (schemas.ESTIMATE, schemas.TRUTH_POSE, schemas.TRUTH_FEET))
        estimate_messages = [(estimate_channel, t_ns, data, 0) for data, t_ns in zip(
            encoder.estimates(estimates), codec.to_ns_many([estimate.t for estimate in estimates]))]
        poses = [(pose_channel, t_ns, data, 0) for t_ns, data in zip(truth_ns, encoder.poses(
            truth_ns, [step.body_position for step in steps], [step.quaternion for step in steps]))]
        feet = [(feet_channel, t_ns, data, 0) for t_ns, data in zip(truth_ns, encoder.feet_of(steps))]
        heavy = [(step.tick, t_ns) for step, t_ns in zip(steps, truth_ns) if step.tick is not None]
        heavy_messages = self._heavy_truth([tick for tick, _ in heavy], [t_ns for _, t_ns in heavy])
        messages: list[tuple[int, int, bytes, int]] = []
        next_sample = next_estimate = 0
        for index, step in enumerate(steps):
            last_sample, last_estimate = next_sample + len(step.samples), next_estimate + len(step.estimates)
            messages += sample_messages[next_sample:last_sample]
            messages += estimate_messages[next_estimate:last_estimate]
            messages += (poses[index], feet[index])
            if step.tick is not None:
                messages += next(heavy_messages)
            next_sample, next_estimate = last_sample, last_estimate
        return messages

    def _heavy_truth(self, ticks: list[Tick], truth_ns: list[int]):
        """Per tick, the (channel, log ns, data, sequence) of its transform, state, contacts, support
        and command."""
        channels, encoder = self._channels, self._encoder
        truths = [tick.truth for tick in ticks]
        commands = [tick.command for tick in ticks]
        transforms = encoder.transforms(truth_ns, [truth.body_position for truth in truths],
                                        [tick.truth_quaternion for tick in ticks])
        supports = [encoder.support(truth.t, tick.support_polygon, truth.com_position[:2], tick.stability_margin)
                    for truth, tick in zip(truths, ticks)]
        columns = zip(transforms, encoder.truth_states(truths),
                      encoder.contacts_of([truth.t for truth in truths], [tick.contacts for tick in ticks]), supports,
                      encoder.commands(commands), truth_ns, codec.to_ns_many([command.t for command in commands]))
        tf, state, contacts, support, command = (channels[topic.name] for topic in (
            schemas.TF, schemas.TRUTH_STATE, schemas.TRUTH_CONTACTS, schemas.TRUTH_SUPPORT, schemas.COMMAND))
        for transform, state_data, contacts_data, support_data, command_data, t_ns, command_ns in columns:
            yield ((tf, t_ns, transform, 0), (state, t_ns, state_data, 0), (contacts, t_ns, contacts_data, 0),
                   (support, t_ns, support_data, 0), (command, command_ns, command_data, 0))


class _Step(NamedTuple):
    """What the messages of every tick need, kept until the next write in place of the tick, which
    is kept only every `truth_every` ticks, for its heavy truth: the other ticks' objects are freed
    at once, while still in the processor's caches (freeing 500 ticks at each write cost ~6 us a tick)."""
    t: float
    body_position: np.ndarray
    quaternion: np.ndarray
    foot_positions: np.ndarray
    foot_contact: np.ndarray
    samples: list
    estimates: list
    tick: Tick | None


_SAMPLES = _Step._fields.index("samples")     # where a pending step (a plain tuple) holds its samples


def run_description(config: "Config", every: int, truth_rate: float) -> dict[str, str]:
    return {"terrain": config.run.terrain, "estimator": config.run.estimator, "gait": config.run.gait,
            "seed": str(config.run.seed), "duration_s": repr(config.run.duration),
            "time_step_s": repr(config.run.time_step), "truth_rate_hz": repr(truth_rate), "truth_every": str(every),
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def truth_every(time_step: float, rate: float = TRUTH_RATE) -> int:
    """Physics steps between two heavy-truth records."""
    return max(1, int(round(1.0 / (rate * time_step))))


def _json_safe(value):
    """Metrics as strict JSON: numpy scalars to Python, non-finite floats to null."""
    if isinstance(value, dict):
        return {str(key): _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@cache
def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    for name in VERSIONED_PACKAGES:
        versions[name] = _version(name)
    return versions


def _version(name: str) -> str:
    try:
        return package_metadata.version(name)
    except package_metadata.PackageNotFoundError:
        return "not installed"
