"""`McapRecorder`: every stream of a run into one MCAP file (topics: docs/dataset.md).

- The file is written as `<path>.partial` and renamed to `<path>` when it is closed, so a file
  with the final name is always complete.
- `record` serialises the tick's messages at once (protobuf's `SerializeToString`) and keeps
  them; every `flush_period` of simulated time they go to mcap's `Writer`, which closes the chunk,
  compresses it (zstd) and writes and flushes it to the file. A process killed outright therefore
  leaves a `.partial` file that is readable up to the last flush (`datasets.reader` recovers it).
  All of it runs in the caller's thread: serialising and `add_message` hold the GIL, as does the
  simulation, so a writer thread would only take turns with the run loop.
- Ctrl-C cannot land inside a write (`datasets.signals`); `finish`, which the run loop calls
  after an interrupt or a divergence too, writes what is pending, the metrics and the summary.
- A write that fails (a full disk) raises its error; the file is not written any further, and
  `finish` raises `WriterFailed` and leaves the `.partial` file as it is.
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
from importlib import metadata as package_metadata
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from datasets import codec, schemas
from datasets.signals import sigint_deferred
from testbed.runtime.parts import part_sources
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

Message = tuple[int, int, bytes, int]       # channel id, log time (ns, also the publish time), data, sequence


class WriterFailed(Exception):
    """A write to the dataset failed earlier; the file was left as it was then."""


class DatasetWriter:
    """An MCAP file of the dataset format: every topic registered, the run description first,
    written under a temporary name until `close`."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.partial_path = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial_path, "wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._failure: BaseException | None = None
        self.closed = False
        self._writing(self._writer.start, profile=PROFILE, library=f"hexapod-testbed/{_version('hexapod-testbed')}")
        self.channels = {topic.name: self._register(topic) for topic in schemas.TOPICS}

    def describe_run(self, run_info: dict[str, str], config: "Config", urdf: str) -> None:
        """Metadata and attachments go before any message, so that even a truncated file can be
        replayed."""
        self._writing(self._describe_run, run_info, config, urdf)

    def write(self, messages: list[Message], flush: bool) -> None:
        """Add the messages; `flush` closes the chunk and puts it on the file, flushed."""
        self._writing(self._write, messages, flush)

    def close(self, metrics: dict, outcome: dict[str, str]) -> None:
        """Write the metrics, the outcome and the summary, then give the file its final name. If a
        write fails, now or before (`WriterFailed`), close the file as it is under its temporary
        name and raise."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writing(self._finish, metrics, outcome)
            self._file.close()
            os.replace(self.partial_path, self.path)
        finally:
            if not self._file.closed:
                self._close_quietly()

    def abandon(self) -> None:
        """Close without a summary and delete the temporary file (nothing worth keeping was written)."""
        self.closed = True
        self._close_quietly()
        self.partial_path.unlink(missing_ok=True)

    def _close_quietly(self) -> None:
        """Close the file after an error, which already says what went wrong."""
        try:
            self._file.close()
        except OSError:
            pass

    def _writing(self, write, *args, **kwargs) -> None:
        """Run one write, safe from Ctrl-C; the first error stops every later write."""
        if self._failure is not None:
            raise WriterFailed(f"{self.partial_path}: an earlier write failed ({self._failure})") from self._failure
        with sigint_deferred():
            try:
                write(*args, **kwargs)
            except Exception as error:
                self._failure = error
                raise

    def _describe_run(self, run_info: dict[str, str], config: "Config", urdf: str) -> None:
        writer = self._writer
        writer.add_metadata("run", {"format_version": schemas.FORMAT_VERSION, **run_info})
        writer.add_metadata("config", {"json": json.dumps(config.to_dict(), sort_keys=True)})
        writer.add_metadata("versions", package_versions())
        created = time.time_ns()
        writer.add_attachment(created, 0, "config.toml", "application/toml", config.to_toml().encode())
        writer.add_attachment(created, 0, "robot.urdf", "application/xml", urdf.encode())

    def _write(self, messages: list[Message], flush: bool) -> None:
        add = self._writer.add_message
        for channel, log_ns, data, sequence in messages:
            add(channel, log_ns, data, log_ns, sequence)
        if flush:
            self._writer.flush()

    def _finish(self, metrics: dict, outcome: dict[str, str]) -> None:
        self._writer.add_metadata("metrics", {"json": json.dumps(_json_safe(metrics), sort_keys=True)})
        self._writer.add_metadata("outcome", outcome)
        self._writer.finish()

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
        self._pending: list[Message] = []       # serialised, not yet written
        self._ticks = 0
        self._samples = 0               # sensor samples so far: the next one's sequence number
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
        self._dataset.describe_run(run_description(config, self._every, self.truth_rate), config, urdf)
        boxes = terrain.boxes
        terrain_data = codec.terrain_message(boxes.centers, boxes.half_extents, boxes.rotations, terrain.name)
        self._dataset.write([(self._channels[schemas.TERRAIN.name], 0, terrain_data, 0)], flush=True)
        self._next_flush_ns = codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def record(self, tick: Tick) -> None:
        started = time.perf_counter()
        t = tick.truth.t
        messages = self._messages(tick, self._ticks % self._every == 0)
        # Added whole or not at all: a Ctrl-C while serialising drops only this tick.
        self._pending += messages
        self._samples += len(tick.samples)
        self._ticks += 1
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

    def _messages(self, tick: Tick, heavy: bool) -> list[Message]:
        """The tick's messages in file order: its samples (numbered on from the samples before
        them), estimates, pose and feet, then with `heavy` its transform, state, contacts, support
        and command."""
        channels, encoder, to_ns = self._channels, self._encoder, codec.to_ns
        truth = tick.truth
        t_ns = to_ns(truth.t)
        messages: list[Message] = []
        sequence = self._samples
        for sample in tick.samples:
            topic, data = encoder.sample(sample)
            messages.append((channels[topic], to_ns(sample.t), data, sequence))
            sequence += 1
        estimate_channel = channels[schemas.ESTIMATE.name]
        for estimate in tick.estimates:
            messages.append((estimate_channel, to_ns(estimate.t), encoder.estimate(estimate), 0))
        messages += ((channels[schemas.TRUTH_POSE.name], t_ns,
                      encoder.pose(t_ns, truth.body_position, tick.truth_quaternion), 0),
                     (channels[schemas.TRUTH_FEET.name], t_ns, encoder.feet(truth), 0))
        if heavy:
            command = tick.command
            support = encoder.support(truth.t, tick.support_polygon, truth.com_position[:2], tick.stability_margin)
            messages += ((channels[schemas.TF.name], t_ns,
                          encoder.transform(t_ns, truth.body_position, tick.truth_quaternion), 0),
                         (channels[schemas.TRUTH_STATE.name], t_ns, encoder.truth_state(truth), 0),
                         (channels[schemas.TRUTH_CONTACTS.name], t_ns, encoder.contacts(truth.t, tick.contacts), 0),
                         (channels[schemas.TRUTH_SUPPORT.name], t_ns, support, 0),
                         (channels[schemas.COMMAND.name], to_ns(command.t), encoder.command(command), 0))
        return messages

    def _write_pending(self, flush: bool) -> None:
        """Hand what is pending to the writer; a Ctrl-C meanwhile waits until it is written."""
        with sigint_deferred():
            pending, self._pending = self._pending, []
            self._dataset.write(pending, flush)


def run_description(config: "Config", every: int, truth_rate: float) -> dict[str, str]:
    return {"terrain": config.run.terrain, "estimator": config.run.estimator, "gait": config.run.gait,
            "seed": str(config.run.seed), "duration_s": repr(config.run.duration),
            "time_step_s": repr(config.run.time_step), "truth_rate_hz": repr(truth_rate), "truth_every": str(every),
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "parts": json.dumps(part_sources(config), sort_keys=True)}


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
