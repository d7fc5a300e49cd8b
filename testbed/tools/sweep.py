"""Sweeps: a grid of runs (terrains x seeds x estimators x sensor presets), one MCAP per run plus an
index of each run's config and metrics, on a local process pool or a Dask distributed cluster.

- A run's name comes from its grid point (`flat_seed003_ekf_default`) and its seed is the grid seed.
- A run is done when its MCAP has its final name (the recorder renames it from `.partial` when it
  closes) and the index holds its row with the same config hash. Running the same sweep again runs
  only what is not done; a folder holding a run of the same name but another config is refused.
- This process alone writes the index (`index.parquet` and `index.csv`), atomically, after every
  finished run: an interrupted sweep keeps every run it finished.
- Local pool: spawn start method (dartpy is not fork-safe once imported), one BLAS/OpenMP thread per
  worker. A worker that dies breaks the pool: its runs in flight go to a new pool, up to
  `max_attempts` attempts each.
- Dask: the scheduler itself reschedules the runs of a lost worker; `retries` covers runs that raise.
  A cluster without any worker for longer than the connect timeout, or whose scheduler is gone,
  stops the sweep (`SweepStopped`) with every finished run kept in the index.
- The cluster must be trusted: Dask unpickles what its workers return. Every returned row is still
  checked (`checked_row`: plain values, the run's name, file and config hash) before it enters the
  index.

docs/sweep.md describes the command, the index columns and the cluster set-up.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import socket
import sys
import time
import uuid
from collections import Counter, deque
from collections.abc import Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, CancelledError, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from itertools import product
from pathlib import Path
from typing import Any, Protocol

from datasets import heightmap_store
from testbed.model.registry import file_stem
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.model.errors import UserError
from testbed.runtime.presets import preset_overrides

INDEX_FILE = "index.parquet"
INDEX_CSV = "index.csv"
MAX_ATTEMPTS = 3
HEALTH_PERIOD = 0.5         # s between two checks of a Dask cluster while no run finishes
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
LEADING_COLUMNS = ("name", "file", "terrain", "seed", "estimator", "sensors", "gait", "contact", "duration_s",
                   "config_hash", "error", "worker", "finished_utc", "elapsed_s", "cpu_s")


# --- the grid --------------------------------------------------------------------------------

@dataclass(frozen=True)
class GridPoint:
    terrain: str
    seed: int
    estimator: str
    sensors: str        # sensor preset (testbed.runtime.presets)

    @property
    def name(self) -> str:
        return f"{file_stem(self.terrain)}_seed{self.seed:03d}_{file_stem(self.estimator)}_{self.sensors}"


@dataclass(frozen=True)
class RunSpec:
    """One run as a worker receives it: plain, picklable data."""
    name: str
    path: str                   # absolute path of the run's MCAP
    config: dict[str, Any]      # the resolved config (Config.to_dict)
    config_hash: str
    sensors: str
    # Files the run needs beside its config (the height map), name -> (media type, data): a worker
    # restores them, so it needs no copy of the user's files.
    attachments: dict[str, tuple[str, bytes]] = field(default_factory=dict)


def expand_grid(terrains: Sequence[str], seeds: Sequence[int], estimators: Sequence[str],
                sensors: Sequence[str]) -> list[GridPoint]:
    """Every combination, terrain-major: the order runs are submitted in."""
    return [GridPoint(*combination) for combination in product(terrains, seeds, estimators, sensors)]


def point_config(point: GridPoint, base: dict[str, Any] | None = None, run: dict[str, Any] | None = None) -> Config:
    """Defaults, then `base` (the user's --config), then the sensor preset, then `run` keys and the
    grid point's terrain, seed and estimator."""
    cfg = config_module.load(None, preset_overrides(point.sensors), base=base)
    grid = {"terrain": point.terrain, "seed": point.seed, "estimator": point.estimator}
    return cfg.replace(run={**(run or {}), **grid})


def config_hash(cfg: Config) -> str:
    """The config's, and the height map's content when it names one."""
    digest = hashlib.sha256(json.dumps(cfg.to_dict(), sort_keys=True).encode())
    for _, data in heightmap_store.attachments_of(cfg).values():
        digest.update(data)
    return digest.hexdigest()[:16]


def make_specs(points: Iterable[GridPoint], folder: Path, base: dict[str, Any] | None = None,
               run: dict[str, Any] | None = None) -> list[RunSpec]:
    """The run of every grid point; building each config validates it before anything runs."""
    folder = Path(folder).absolute()
    specs = []
    for point in points:
        cfg = point_config(point, base, run)
        specs.append(RunSpec(point.name, str(folder / f"{point.name}.mcap"), cfg.to_dict(), config_hash(cfg),
                             point.sensors, heightmap_store.attachments_of(cfg)))
    return specs


class SweepStopped(Exception):
    """The sweep cannot go on (the cluster lost its workers or its scheduler); finished runs are kept."""


class InvalidRow(ValueError):
    """A worker returned something that is not the index row of the run it was given."""


ROW_VALUE_TYPES = (str, int, float, bool, type(None))
MAX_ROW_COLUMNS = 200
MAX_TEXT = 10_000


def checked_row(row: Any, spec: RunSpec) -> dict[str, Any]:
    """`row` if it is the index row of `spec`: a dict of at most MAX_ROW_COLUMNS plain values
    (str, int, float, bool, None) under plain names, with the run's name, its file (a plain file
    name in the sweep folder) and the config hash the run was given; else InvalidRow."""
    if type(row) is not dict or len(row) > MAX_ROW_COLUMNS:
        raise InvalidRow(f"not a table of at most {MAX_ROW_COLUMNS} columns ({type(row).__name__})")
    for key, value in row.items():
        if type(key) is not str or not key.isidentifier() or len(key) > 100:
            raise InvalidRow(f"a column name that is not a plain name ({str(key)[:40]!r})")
        if type(value) not in ROW_VALUE_TYPES or (type(value) is str and len(value) > MAX_TEXT):
            raise InvalidRow(f"column {key} holds a {type(value).__name__}, not a plain value")
    expected = {"name": spec.name, "file": Path(spec.path).name, "config_hash": spec.config_hash}
    for key, value in expected.items():
        if row.get(key) != value:
            raise InvalidRow(f"{key} is {str(row.get(key))[:80]!r}, not {value!r}")
    return row


# --- one run, on a worker --------------------------------------------------------------------

def execute(spec: RunSpec) -> dict[str, Any]:
    """Simulate and record one run; its index row. Runs on a worker process."""
    from datasets.recorder import McapRecorder
    from testbed.runtime.runner import run

    started, cpu_started = time.perf_counter(), time.process_time()
    attachments = {name: data for name, (_, data) in spec.attachments.items()}
    cfg = config_module.from_dict(heightmap_store.restored_config(spec.config, attachments, Path(spec.path)))
    outcome = run(cfg, McapRecorder(spec.path))
    if outcome.interrupted:
        raise RuntimeError(f"{spec.name} was interrupted")
    cost = {"elapsed_s": time.perf_counter() - started, "cpu_s": time.process_time() - cpu_started}
    return index_row(spec, cfg, outcome.metrics, outcome.error, cost)


def index_row(spec: RunSpec, cfg: Config, metrics: dict[str, Any], error: str | None,
              cost: dict[str, float] | None = None) -> dict[str, Any]:
    row: dict[str, Any] = {
        "name": spec.name, "file": Path(spec.path).name, "terrain": cfg.run.terrain, "seed": cfg.run.seed,
        "estimator": cfg.run.estimator, "sensors": spec.sensors, "gait": cfg.run.gait, "contact": cfg.run.contact,
        "duration_s": cfg.run.duration, "config_hash": spec.config_hash, "error": error or "",
        "worker": f"{socket.gethostname()}:{os.getpid()}",
        "finished_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"), **(cost or {})}
    for key, value in metrics.items():
        row[f"metric_{key}" if key in row else key] = _plain(value)
    return row


def _plain(value: Any) -> Any:
    if type(value).__module__ == "numpy":
        value = value.tolist()                  # numpy scalar or array
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return value


# --- the index -------------------------------------------------------------------------------

class Index:
    """The rows of a sweep folder, keyed by run name; saved as Parquet and CSV."""

    def __init__(self, folder: Path, rows: dict[str, dict[str, Any]] | None = None):
        self.folder = Path(folder)
        self.rows = rows or {}

    @classmethod
    def load(cls, folder: Path) -> "Index":
        import pyarrow.parquet as pq

        path = Path(folder) / INDEX_FILE
        if not path.exists():
            return cls(folder)
        try:
            return cls(folder, {row["name"]: row for row in pq.read_table(path).to_pylist()})
        except Exception as error:   # pyarrow raises several types for a damaged file; KeyError: no names
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise UserError(f"cannot read the sweep index {path}: {reason} (move it away to start afresh)") from None

    def pending(self, specs: Sequence[RunSpec]) -> list[RunSpec]:
        """The runs not done yet; a run recorded here with another config is an error."""
        for spec in specs:
            row = self.rows.get(spec.name)
            if row is not None and row.get("config_hash") != spec.config_hash:
                raise UserError(f"{self.folder} already holds run {spec.name} with another config "
                                f"({_difference(row, spec)}): choose another --out")
        return [spec for spec in specs if spec.name not in self.rows or not Path(spec.path).exists()]

    def add(self, row: dict[str, Any]) -> None:
        self.rows[row["name"]] = row

    def save(self) -> None:
        import pyarrow.csv as pa_csv
        import pyarrow.parquet as pq

        if not self.rows:
            return
        table = rows_table([self.rows[name] for name in sorted(self.rows)])
        _atomic_write(self.folder / INDEX_FILE, lambda path: pq.write_table(table, path))
        _atomic_write(self.folder / INDEX_CSV, lambda path: pa_csv.write_csv(table, path))


def _difference(row: dict[str, Any], spec: RunSpec) -> str:
    run = spec.config["run"]
    for column, key in (("duration_s", "duration"), ("gait", "gait"), ("contact", "contact")):
        if row.get(column) != run[key]:
            return f"run.{key} {row.get(column)} there, {run[key]} here"
    return f"config hash {row.get('config_hash')} there, {spec.config_hash} here"


def rows_table(rows: list[dict[str, Any]]):
    """A pyarrow Table of index rows: the grid columns first, then the metrics in first-seen order."""
    import pyarrow as pa

    names = [column for column in LEADING_COLUMNS if any(column in row for row in rows)]
    for row in rows:
        names.extend(key for key in row if key not in names)
    return pa.table({name: _column([row.get(name) for row in rows]) for name in names})


def _column(values: list[Any]):
    import pyarrow as pa

    kinds = {type(value) for value in values if value is not None}
    if not kinds or kinds <= {int, float}:
        return pa.array(values, type=pa.int64() if kinds == {int} else pa.float64())
    if kinds == {bool}:
        return pa.array(values, type=pa.bool_())
    return pa.array([None if value is None else str(value) for value in values], type=pa.string())


def _atomic_write(path: Path, write) -> None:
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(temporary)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


# --- where runs execute ----------------------------------------------------------------------

class Backend(Protocol):
    window: int             # runs in flight at most
    resubmits: bool         # the sweep resubmits failed runs itself (the Dask scheduler retries on its own)

    def submit(self, spec: RunSpec) -> tuple[Future, int]: ...
    def lost(self, generation: int) -> None: ...
    def close(self, abort: bool) -> None: ...


class LocalPool:
    """A process pool (spawn start method) that is replaced when one of its workers dies.
    At most `workers` runs are in flight, so a broken pool takes down only runs that had started."""

    resubmits = True

    def __init__(self, workers: int):
        self.window = workers
        self.generation = 0
        self._executor: ProcessPoolExecutor | None = None

    def submit(self, spec: RunSpec) -> tuple[Future, int]:
        if self._executor is None:
            self._executor = self._start()
        try:
            return self._executor.submit(execute, spec), self.generation
        except BrokenProcessPool:        # broke since the last submit: go on with a fresh pool
            self.lost(self.generation)
            return self.submit(spec)

    def lost(self, generation: int) -> None:
        """A future of pool `generation` saw its pool break: replace it, once."""
        if generation == self.generation and self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
            self.generation += 1

    def close(self, abort: bool) -> None:
        if self._executor is None:
            return
        self._executor.shutdown(wait=not abort, cancel_futures=True)
        if abort:       # runs in flight stop now; their `.partial` files are redone on resume
            for process in multiprocessing.active_children():
                process.terminate()
        self._executor = None

    def _start(self) -> ProcessPoolExecutor:
        for name in THREAD_VARIABLES:           # inherited by the spawned workers
            os.environ.setdefault(name, "1")
        return ProcessPoolExecutor(self.window, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_ignore_sigint)


def _ignore_sigint() -> None:
    """Ctrl-C reaches the whole process group; the sweep process alone decides what stops."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class DaskPool:
    """Runs on a Dask distributed cluster through its concurrent.futures executor."""

    resubmits = False

    def __init__(self, client, max_attempts: int = MAX_ATTEMPTS, patience: float = 5.0):
        """`patience`: seconds the cluster may be without any worker before the sweep stops."""
        self.client = client
        self.patience = patience
        self.window = 1 << 30       # everything at once: the scheduler balances the workers
        self._executor = client.get_executor(retries=max_attempts - 1, pure=False)
        self._without_workers_since: float | None = None
        self._quiet = _QuietLogs()       # the client's own logs of a lost connection: the sweep says it in one line

    def check(self) -> None:
        """SweepStopped if the scheduler is gone, or the cluster has had no worker for `patience` seconds."""
        address = getattr(self.client.scheduler, "address", "?")
        if self.client.status != "running":        # "connecting": it lost its scheduler, and retries
            raise SweepStopped(f"the Dask scheduler at {address} is gone (the client is {self.client.status})")
        try:
            workers = self.client.scheduler_info().get("workers", {})
        except Exception as error:     # noqa: BLE001 - whatever the client raises, the scheduler is unreachable
            raise SweepStopped(f"the Dask scheduler at {address} is gone ({type(error).__name__})") from None
        now = time.monotonic()
        if workers:
            self._without_workers_since = None
        elif self._without_workers_since is None:
            self._without_workers_since = now
        elif now - self._without_workers_since > self.patience:
            raise SweepStopped(f"the Dask cluster at {address} has had no worker for {self.patience:g} s")

    def submit(self, spec: RunSpec) -> tuple[Future, int]:
        return self._executor.submit(execute, spec, key=f"sweep-{spec.name}-{uuid.uuid4().hex[:8]}"), 0

    def lost(self, generation: int) -> None:
        """Nothing to do: the scheduler reschedules the runs of a lost worker."""

    def close(self, abort: bool) -> None:
        try:
            if abort:
                self._executor.shutdown(wait=False)
            self.client.close(timeout=self.patience)
        except Exception:   # noqa: BLE001 - a client whose scheduler is gone closes as it can
            pass
        finally:
            self._quiet.restore()


class _QuietLogs:
    """Dask's, tornado's and asyncio's loggers at CRITICAL until `restore`."""

    NAMES = ("distributed", "tornado", "asyncio")

    def __init__(self):
        import logging
        names = [name for name in logging.root.manager.loggerDict if name.split(".")[0] in self.NAMES]
        self._loggers = [logging.getLogger(name) for name in {*self.NAMES, *names}]
        self._levels = [logger.level for logger in self._loggers]
        for logger in self._loggers:
            logger.setLevel(logging.CRITICAL)

    def restore(self) -> None:
        for logger, level in zip(self._loggers, self._levels):
            logger.setLevel(level)


def connect(address: str, timeout: float):
    """A Dask client of the scheduler at `address`; UserError when it cannot be reached in time."""
    import logging

    from distributed import Client

    loggers = [logging.getLogger(name) for name in ("distributed", "tornado", "asyncio")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise UserError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s ({reason})") from None
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


# --- the sweep -------------------------------------------------------------------------------

@dataclass
class Summary:
    total: int
    skipped: int                        # done before this sweep started
    executed: int = 0                   # finished now
    retried: int = 0                    # resubmissions after a lost worker or an error
    failed: list[str] = field(default_factory=list)
    interrupted: bool = False


class _Sweep:
    """The submit / collect loop: runs in flight, attempts, the index, the progress bar."""

    def __init__(self, backend: Backend, index: Index, summary: Summary, max_attempts: int, bar):
        self.backend, self.index, self.summary, self.bar = backend, index, summary, bar
        self.max_attempts = max_attempts
        self.queue: deque[RunSpec] = deque()
        self.running: dict[Future, tuple[RunSpec, int]] = {}
        self.attempts: Counter[str] = Counter()

    def run(self, todo: Sequence[RunSpec]) -> None:
        self.queue.extend(todo)
        while self.queue or self.running:
            while self.queue and len(self.running) < self.backend.window:
                spec = self.queue.popleft()
                self.attempts[spec.name] += 1
                future, generation = self.backend.submit(spec)
                self.running[future] = (spec, generation)
            finished, _ = wait(list(self.running), timeout=HEALTH_PERIOD, return_when=FIRST_COMPLETED)
            if not finished and hasattr(self.backend, "check"):
                self.backend.check()
            for future in finished:
                self.collect(future, *self.running.pop(future))

    def collect(self, future: Future, spec: RunSpec, generation: int) -> None:
        try:
            row = future.result()
        except (BrokenProcessPool, CancelledError):
            if hasattr(self.backend, "check"):
                self.backend.check()        # a scheduler that is gone is said so, not taken for a lost worker
            self.backend.lost(generation)
            self.retry(spec, "its worker died", always=True)
            return
        except Exception as error:
            self.retry(spec, f"{type(error).__name__}: {error}", always=False)
            return
        try:
            row = checked_row(row, spec)
        except InvalidRow as error:
            self.summary.failed.append(spec.name)
            self._say(f"sweep: {spec.name}: its worker returned an invalid index row ({error}); not kept")
        else:
            self.index.add(row)
            self.index.save()
            self.summary.executed += 1
            self.bar.update(1)

    def retry(self, spec: RunSpec, reason: str, always: bool) -> None:
        again = (always or self.backend.resubmits) and self.attempts[spec.name] < self.max_attempts
        if again:
            self.queue.appendleft(spec)
            self.summary.retried += 1
            self._say(f"sweep: {spec.name}: {reason}; attempt {self.attempts[spec.name] + 1} of {self.max_attempts}")
        else:
            self.summary.failed.append(spec.name)
            tries = f" after {self.attempts[spec.name]} attempt(s)" if self.backend.resubmits else ""
            self._say(f"sweep: {spec.name} failed{tries}: {reason}")
        self.bar.set_postfix(retried=self.summary.retried, failed=len(self.summary.failed))

    def _say(self, text: str) -> None:
        self.bar.write(text, file=sys.stderr)     # above the progress bar, on stderr like it


def run_sweep(todo: Sequence[RunSpec], index: Index, backend: Backend, total: int,
              max_attempts: int = MAX_ATTEMPTS, bar=None) -> Summary:
    """Run `todo` (the pending runs of a sweep of `total`) on `backend`, adding each finished run to
    `index`. Ctrl-C stops the sweep with every finished run kept (`Summary.interrupted`)."""
    summary = Summary(total=total, skipped=total - len(todo))
    bar = bar if bar is not None else _NoBar()
    sweep = _Sweep(backend, index, summary, max_attempts, bar)
    try:
        sweep.run(todo)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        backend.close(abort=bool(sweep.running) or summary.interrupted)
        index.save()
    return summary


class _NoBar:
    def update(self, n: int = 1) -> None: ...
    def write(self, text: str, file=None) -> None: ...
    def set_postfix(self, **values) -> None: ...
