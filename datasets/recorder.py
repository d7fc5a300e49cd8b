"""`McapRecorder`: every stream of a run into one MCAP file (topics: docs/dataset.md).

- The file is written as `<path>.partial` and renamed to `<path>` when it is closed, so a file
  with the final name is always complete.
- `record` only keeps the tick (its arrays are new at every step, never modified afterwards);
  every `flush_period` of simulated time the pending ticks are serialised, all in one loop, and go
  to the writer, which closes a compressed chunk and flushes it to disk.
  A process killed outright therefore leaves a `.partial` file whose chunks up to the last flush
  are readable (`datasets.reader` recovers them).
- Ctrl-C cannot land inside a write (`datasets.signals`); `finish`, which the run loop calls
  after an interrupt or a divergence too, writes what is pending, the metrics and the summary.
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
from mcap.writer import CompressionType
from mcap_protobuf.schema import build_file_descriptor_set

from datasets import codec, schemas
from datasets.mcap_batch import BatchWriter
from datasets.signals import sigint_deferred
from testbed.recording import Tick

if TYPE_CHECKING:
    from testbed.config import Config
    from testbed.terrain import Terrain

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
        self._writer = BatchWriter(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
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
        """(channel id, log ns, data, sequence) messages; `flush` closes the chunk and flushes the file."""
        with sigint_deferred():
            self._writer.add_messages(messages)
            if flush:
                self._writer.flush()

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
                self._file.close()

    def abandon(self) -> None:
        """Close without a summary and delete the temporary file (nothing worth keeping was written)."""
        self.closed = True
        self._file.close()
        self.partial_path.unlink(missing_ok=True)

    def _register(self, topic: schemas.Topic) -> int:
        descriptor_set = build_file_descriptor_set(topic.message_class).SerializeToString()
        schema_id = self._writer.register_schema(topic.message_class.DESCRIPTOR.full_name, SchemaEncoding.Protobuf,
                                                 descriptor_set)
        return self._writer.register_channel(topic.name, MessageEncoding.Protobuf, schema_id)


class McapRecorder:
    """Implements `testbed.recording.Recorder`."""

    def __init__(self, path: str | Path, truth_rate: float = TRUTH_RATE, flush_period: float = FLUSH_PERIOD):
        self.path = Path(path)
        self.truth_rate = truth_rate
        self.flush_period = flush_period
        self.busy_s = 0.0               # wall time spent inside the recorder
        self._dataset: DatasetWriter | None = None
        self._encoder = codec.Encoder()
        self._channels: dict[str, int] = {}
        self._pending_ticks: list[Tick] = []     # recorded, not yet encoded and written
        self._ticks = 0
        self._encoded_ticks = 0
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
        self._dataset.describe_run(run_description(config, self._every, self.truth_rate), config, urdf)
        boxes = terrain.boxes
        terrain_data = codec.terrain_message(boxes.centers, boxes.half_extents, boxes.rotations, terrain.name)
        self._dataset.add_many([(self._channels[schemas.TERRAIN.name], 0, terrain_data, 0)], flush=True)
        self._next_flush_ns = codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def record(self, tick: Tick) -> None:
        started = time.perf_counter()
        self._pending_ticks.append(tick)
        self._ticks += 1
        self._last_t = tick.truth.t
        t_ns = codec.to_ns(tick.truth.t)
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
        """Encode the ticks recorded since the last write (in one loop, whose code stays in the
        processor's caches, rather than between the run loop's other stages) and write them."""
        messages: list[tuple[int, int, bytes, int]] = []
        for tick in self._pending_ticks:
            self._encode(tick, messages)
        self._pending_ticks.clear()
        self._dataset.add_many(messages, flush)

    def _encode(self, tick: Tick, messages: list[tuple[int, int, bytes, int]]) -> None:
        truth, channels, encoder = tick.truth, self._channels, self._encoder
        t_ns = codec.to_ns(truth.t)
        for sample in tick.samples:
            topic, data = encoder.sample(sample)
            messages.append((channels[topic], codec.to_ns(sample.t), data, self._samples))
            self._samples += 1
        estimate_channel = channels[schemas.ESTIMATE.name]
        for estimate in tick.estimates:
            messages.append((estimate_channel, codec.to_ns(estimate.t), encoder.estimate(estimate), 0))
        messages.append((channels[schemas.TRUTH_POSE.name], t_ns,
                         encoder.pose(t_ns, truth.body_position, tick.truth_quaternion), 0))
        messages.append((channels[schemas.TRUTH_FEET.name], t_ns, encoder.feet(truth), 0))
        if self._encoded_ticks % self._every == 0:
            self._encode_heavy_truth(tick, t_ns, messages)
        self._encoded_ticks += 1

    def _encode_heavy_truth(self, tick: Tick, t_ns: int, messages: list[tuple[int, int, bytes, int]]) -> None:
        truth, channels, encoder = tick.truth, self._channels, self._encoder
        messages.append((channels[schemas.TF.name], t_ns,
                         encoder.transform(t_ns, truth.body_position, tick.truth_quaternion), 0))
        messages.append((channels[schemas.TRUTH_STATE.name], t_ns, encoder.truth_state(truth), 0))
        messages.append((channels[schemas.TRUTH_CONTACTS.name], t_ns, encoder.contacts(truth.t, tick.contacts), 0))
        messages.append((channels[schemas.TRUTH_SUPPORT.name], t_ns,
                         encoder.support(truth.t, tick.support_polygon, truth.com_position[:2], tick.stability_margin),
                         0))
        messages.append((channels[schemas.COMMAND.name], codec.to_ns(tick.command.t), encoder.command(tick.command), 0))


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
