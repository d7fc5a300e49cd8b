"""Progress bars in simulated seconds, with the real-time factor, for runs and replays.

`ProgressRecorder` wraps a recorder of the run loop (`testbed.runtime.recording.Recorder`) and
moves the bar as the ticks pass; `with_progress` wraps the samples a replay feeds its estimator.
Both update the bar every PROGRESS_PERIOD of simulated time, so the cost per tick is a comparison.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, TYPE_CHECKING

from tqdm.auto import tqdm

if TYPE_CHECKING:
    from sensors.samples import Sample
    from testbed.runtime.config import Config
    from testbed.runtime.recording import Recorder, Tick
    from testbed.world.terrain import Terrain

DEFAULT_SIZE = (100, 24)    # columns, lines
PROGRESS_PERIOD = 0.1       # s of simulated time between two updates of a bar
PROGRESS_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s simulated [{elapsed}<{remaining}{postfix}]"


def show_progress(quiet: bool = False, stream: IO[str] | None = None) -> bool:
    """Whether a command shows a bar: on a terminal, unless asked to be quiet."""
    stream = sys.stderr if stream is None else stream
    return not quiet and stream.isatty()


class SimTimeBar:
    """A tqdm bar over `total` simulated seconds; its postfix is the real-time factor so far."""

    def __init__(self, total: float, desc: str, stream: IO[str] | None = None):
        stream = sys.stderr if stream is None else stream
        self.bar = tqdm(total=total, desc=desc, unit="sim s", bar_format=PROGRESS_FORMAT, file=stream,
                        **_size(stream))
        self.started = time.perf_counter()
        self.next_update = 0.0

    def reach(self, t: float) -> None:
        """Move the bar to `t` simulated seconds, at most every PROGRESS_PERIOD."""
        if t < self.next_update:
            return
        self.next_update = t + PROGRESS_PERIOD
        self.bar.n = min(t, self.bar.total)
        wall = time.perf_counter() - self.started
        if wall > 0:
            self.bar.set_postfix_str(f"x{t / wall:.2f} real time", refresh=False)
        self.bar.refresh()

    def close(self, t: float | None = None) -> None:
        if t is not None:
            self.next_update = 0.0
            self.reach(t)
        self.bar.close()


def _size(stream: IO[str]) -> dict[str, int]:
    """tqdm's `ncols` and `nrows`: the terminal's; a terminal that reports a size of zero (a bare
    pseudo-terminal), where tqdm would draw nothing, gets DEFAULT_SIZE."""
    try:
        columns, lines = os.get_terminal_size(stream.fileno())
    except (OSError, ValueError, AttributeError):
        columns, lines = 0, 0
    return {"ncols": columns or DEFAULT_SIZE[0], "nrows": lines or DEFAULT_SIZE[1]}


class ProgressRecorder:
    """A recorder that also shows the simulated time on a progress bar (implements `Recorder`)."""

    def __init__(self, inner: "Recorder", stream: IO[str] | None = None, desc: str = "run"):
        self.inner = inner
        self.desc = desc
        self.path = getattr(inner, "path", None)       # the file recorded to, if any
        self.stream = stream
        self.bar: SimTimeBar | None = None

    def start(self, config: "Config", urdf: str, terrain: "Terrain") -> None:
        self.bar = SimTimeBar(config.run.duration, self.desc, self.stream)
        self.inner.start(config, urdf, terrain)

    def record(self, tick: "Tick") -> None:
        self.inner.record(tick)
        self.bar.reach(tick.truth.t)

    def finish(self, metrics: dict, error: str | None) -> None:
        try:
            self.inner.finish(metrics, error)
        finally:
            if self.bar is not None:
                self.bar.close(metrics.get("sim_time_s"))


def with_progress(samples: Iterable["Sample"], span_s: float, desc: str = "replay",
                  stream: IO[str] | None = None) -> Iterator["Sample"]:
    """The samples, in order, moving a bar over their time span `span_s` (s) as they are consumed."""
    return _advancing(samples, SimTimeBar(span_s, desc, stream))


def _advancing(samples: Iterable["Sample"], bar: SimTimeBar) -> Iterator["Sample"]:
    first = elapsed = None
    try:
        for sample in samples:
            first = sample.t if first is None else first
            elapsed = sample.t - first
            bar.reach(elapsed)
            yield sample
    finally:
        bar.close(elapsed)
