"""`McapRecorder`: every stream of a run into one MCAP file (topics: docs/dataset.md).

- The file is written as `<path>.partial` and renamed to `<path>` when it is closed, so a file
  with the final name is always complete.
- `record` keeps the tick; every `flush_period` of simulated time the pending ticks go to a
  writer process (`datasets.writer.WriterProcess`) as columns (`codec.TickColumns`: each
  message kind's fields stacked into arrays), one pickle per handover. The writer serialises the
  messages from the columns (protobuf's `SerializeToString`), adds them through mcap's `Writer`
  and flushes: the chunk is closed, compressed (zstd), written and flushed to the file. The
  serialising and writing run in a process because the simulation holds the GIL through its
  whole step; a thread would only take turns with the run loop.
- A sensor plugin's sample type is recorded on its own topic (`schemas.sample_topic`), which the
  writer registers when it first sees one; a tick with a sample of a type that cannot be
  recorded raises TypeError in `record` and is not recorded.
- A process killed outright leaves a valid `.partial` file holding every message handed over: the
  writer sees its pipe close and writes the summary. What was not handed over yet is lost.
- The writer ignores Ctrl-C (it reaches the whole process group); a Ctrl-C while the columns are
  gathered leaves the ticks pending, one during a handover is held until the batch is handed over
  (`datasets.signals`); `finish`, which the run loop calls after an interrupt or a divergence
  too, hands over what is pending, the metrics and the summary, and returns when the writer has
  closed and renamed the file.
- Two processes recording to the same path: the second stops at `start` with OutputBusy (the
  `.partial` file is locked while written); the final rename replaces an existing file only with
  `replace`.
- A write that fails (a full disk) is raised as `WriterFailed` at the next handover or by `finish`;
  the file is not written any further and keeps its `.partial` name.
- Sensor samples, estimates, the body pose and the feet (what scoring reads) are recorded at every
  occurrence; the heavy truth (state, contacts, support polygon) and the commands every
  `truth_every` physics steps.
"""

from __future__ import annotations

import json
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from datasets import codec, schemas
from datasets.signals import sigint_deferred
from datasets.writer import (PARTIAL_SUFFIX, DatasetWriter, OutputBusy, WriterFailed, WriterProcess, partial_path_of,
                             running_cpu)
from testbed.runtime.parts import part_sources
from testbed.runtime.recording import Tick

__all__ = ["FLUSH_PERIOD", "PARTIAL_SUFFIX", "TRUTH_RATE", "DatasetWriter", "McapRecorder", "OutputBusy", "WriterFailed",
           "run_description", "truth_every"]

if TYPE_CHECKING:
    from testbed.runtime.config import Config
    from testbed.world.terrain import Terrain

TRUTH_RATE = 200.0          # Hz, heavy truth (state, contacts, support polygon) and commands
FLUSH_PERIOD = 0.5          # s of simulated time per chunk


class McapRecorder:
    """Implements `testbed.runtime.recording.Recorder`."""

    def __init__(self, path: str | Path, truth_rate: float = TRUTH_RATE, flush_period: float = FLUSH_PERIOD,
                 replace: bool = True):
        """`replace`: the finished file may replace an existing one (else `finish` raises OutputBusy
        if the name was taken meanwhile, and the file keeps its `.partial` name)."""
        self.path = Path(path)
        self.replace = replace
        self.truth_rate = truth_rate
        self.flush_period = flush_period
        self.busy_s = 0.0               # wall time spent inside the recorder
        self._dataset: WriterProcess | None = None
        self._pending: list[Tick] = []          # not handed over yet
        self._sample_types: set[type] = set()   # the sample types that can be recorded, seen so far
        self._ticks = 0                 # ticks handed over
        self._samples = 0               # sensor samples handed over: the next one's sequence number
        self._every = 1
        self._next_flush_ns = 0
        self._last_t = 0.0

    @property
    def partial_path(self) -> Path:
        return partial_path_of(self.path)

    @property
    def writer_pid(self) -> int | None:
        """The writer process's id, from `start` on."""
        return self._dataset.pid if self._dataset is not None else None

    # --- Recorder protocol --------------------------------------------------------------------

    def start(self, config: "Config", urdf: str, terrain: "Terrain") -> None:
        started = time.perf_counter()
        self._every = truth_every(config.run.time_step, self.truth_rate)
        with sigint_deferred():     # a Ctrl-C now would leave the writer without its file's head
            self._dataset = WriterProcess(self.path, run_description(config, self._every, self.truth_rate), config,
                                          urdf, self.replace)
        boxes = terrain.boxes
        terrain_data = codec.terrain_message(boxes.centers, boxes.half_extents, boxes.rotations, terrain.name)
        description = codec.robot_description_message(urdf)
        self._dataset.write([(self._dataset.channels[schemas.TERRAIN.name], 0, terrain_data, 0),
                             (self._dataset.channels[schemas.ROBOT_DESCRIPTION.name], 0, description, 0)], flush=True)
        self._next_flush_ns = codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def record(self, tick: Tick) -> None:
        started = time.perf_counter()
        if not self._sample_types.issuperset(map(type, tick.samples)):
            self._accept_sample_types(tick.samples)
        self._pending.append(tick)
        self._last_t = t = tick.truth.t
        t_ns = codec.to_ns(t)
        if t_ns >= self._next_flush_ns:
            self._hand_over(flush=True)
            self._next_flush_ns = t_ns + codec.to_ns(self.flush_period)
        self.busy_s += time.perf_counter() - started

    def finish(self, metrics: dict, error: str | None) -> None:
        """Close the file validly and give it its final name. Safe to call more than once."""
        if self._dataset is None or self._dataset.closed:
            return
        started = time.perf_counter()
        try:
            self._hand_over(flush=False)
        finally:
            ticks = self._ticks + len(self._pending)
            outcome = {"error": error or "", "ticks": str(ticks), "sim_time_s": repr(self._last_t),
                       "recording_wall_s": repr(self.busy_s + time.perf_counter() - started)}
            self._dataset.close(metrics, outcome)

    # --- internals ----------------------------------------------------------------------------

    def _accept_sample_types(self, samples: list) -> None:
        """TypeError, and the tick is not recorded, if a sample's type cannot be recorded."""
        for sample in samples:
            codec.sample_topic(type(sample))
            self._sample_types.add(type(sample))

    def _hand_over(self, flush: bool) -> None:
        """Hand the pending ticks to the writer as columns; a Ctrl-C while they are gathered leaves
        them pending, one meanwhile handing them over waits until they are handed over."""
        pending = self._pending
        first_tick = self._ticks
        heavy = [(first_tick + index) % self._every == 0 for index in range(len(pending))]
        columns = codec.TickColumns.of(pending, heavy, self._samples)
        with sigint_deferred():
            self._pending = []
            self._ticks += len(pending)
            self._samples += len(columns.sample_kinds)
            self._dataset.keep_off_cpu(running_cpu())
            self._dataset.write_ticks(columns, flush)


def run_description(config: "Config", every: int, truth_rate: float) -> dict[str, str]:
    return {"terrain": config.run.terrain, "estimator": config.run.estimator, "gait": config.run.gait,
            "seed": str(config.run.seed), "duration_s": repr(config.run.duration),
            "time_step_s": repr(config.run.time_step), "truth_rate_hz": repr(truth_rate), "truth_every": str(every),
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "parts": json.dumps(part_sources(config), sort_keys=True)}


def truth_every(time_step: float, rate: float = TRUTH_RATE) -> int:
    """Physics steps between two heavy-truth records."""
    return max(1, int(round(1.0 / (rate * time_step))))
