"""`testbed sweep`: the command line of `testbed.tools.sweep` (docs/sweep.md).

testbed/cli.py calls `add_subcommands` while building its parser. Bad input raises UserError (one
line on stderr, exit code 2) before anything is written or any run starts.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import sys
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

from testbed.runtime import config as config_module
from estimators.registry import ESTIMATORS, resolve_estimator
from testbed.control.gait import GAITS
from testbed.tools import sweep
from testbed.world.terrain import TERRAINS
from testbed.model.errors import UserError
from testbed.runtime.presets import DEFAULT_PRESET, preset_names

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130
SCHEMES = ("tcp", "tls")
DEFAULT_GAIT = "tripod"
MAX_RUNS = 100_000          # runs of one sweep: its index and the specs stay small


def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser(
        "sweep", help="a grid of runs (terrains x seeds x estimators x sensor presets): one MCAP per run and an index")
    parser.add_argument("--terrains", metavar="T1,T2", help=f"{', '.join(TERRAINS.names())} or MODULE:CLASS (default: the config's terrain)")
    parser.add_argument("--seeds", type=int, default=1, metavar="N", help="N seeds per grid point (default 1)")
    parser.add_argument("--first-seed", type=int, default=0, metavar="S", help="seeds run S ... S+N-1 (default 0)")
    parser.add_argument("--estimators", metavar="E1,E2",
                        help=f"none, {', '.join(ESTIMATORS.names())} or MODULE:CLASS (default: the config's estimator)")
    parser.add_argument("--sensors", default=DEFAULT_PRESET, metavar="P1,P2",
                        help=f"sensor presets: {', '.join(preset_names())} (default {DEFAULT_PRESET})")
    parser.add_argument("--duration", type=float, help="simulated seconds per run (default: the config's)")
    parser.add_argument("--gait", help=f"{' | '.join(GAITS.names())} | MODULE:NAME (default: the --config file's, else tripod)")
    parser.add_argument("--config", type=Path, help="TOML file overriding testbed/defaults.toml for every run")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR",
                        help="folder of the runs and the index; run the same command again to resume")
    parser.add_argument("--workers", type=int, help="local worker processes (default: the number of CPUs)")
    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler")
    parser.add_argument("--connect-timeout", type=float, default=5.0, metavar="SECONDS",
                        help="give up reaching the scheduler after this long (default 5)")
    parser.add_argument("--max-attempts", type=int, default=sweep.MAX_ATTEMPTS, metavar="N",
                        help=f"attempts per run when workers die or runs fail (default {sweep.MAX_ATTEMPTS})")
    parser.set_defaults(handler=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    _check_numbers(args)
    folder = _check_folder(args.out)
    specs = sweep.make_specs(_grid(args), folder, _base(args.config), _run_keys(args))
    started = time.perf_counter()
    with ExitStack() as stack:
        locked = folder.is_dir()
        if locked:
            stack.enter_context(_locked(folder))
        index = sweep.Index.load(folder)
        todo = index.pending(specs)
        if not todo:
            print(f"sweep: all {_runs(len(specs))} in {folder} are done already; index {folder / sweep.INDEX_FILE}")
            return EXIT_OK
        backend = _backend(args, len(todo))
        folder.mkdir(parents=True, exist_ok=True)
        if not locked:
            stack.enter_context(_locked(folder))
        try:
            summary = _run(todo, index, backend, len(specs), args.max_attempts)
        except sweep.SweepStopped as error:
            done = len([spec for spec in specs if spec.name in index.rows])
            print(f"testbed: sweep stopped: {error}; {done} of {_runs(len(specs))} done, index "
                  f"{folder / sweep.INDEX_FILE} saved; run the same command again to resume", file=sys.stderr)
            return EXIT_FAILED
    _warn_unseen(folder, index, todo)
    return _report(summary, folder, time.perf_counter() - started)


# --- input -----------------------------------------------------------------------------------

def _check_numbers(args: argparse.Namespace) -> None:
    if not 1 <= args.seeds <= MAX_RUNS:
        raise UserError(f"--seeds must be 1 ... {MAX_RUNS}, got {args.seeds}")
    if not 0 <= args.first_seed < 2**62:
        raise UserError(f"--first-seed must be 0 ... 2^62, got {args.first_seed}")
    if not 1 <= args.max_attempts <= 100:
        raise UserError(f"--max-attempts must be 1 ... 100, got {args.max_attempts}")
    if args.scheduler is not None:
        if args.workers is not None:
            raise UserError("--workers is for the local pool; with --scheduler the cluster's workers run the sweep")
        _check_address(args.scheduler)
        if not 0 < args.connect_timeout <= 3600:
            raise UserError(f"--connect-timeout must be positive, got {args.connect_timeout}")
    elif args.workers is not None and not 1 <= args.workers <= 1024:
        raise UserError(f"--workers must be 1 ... 1024, got {args.workers}")


def _check_address(address: str) -> None:
    scheme, separator, rest = address.partition("://")
    host, _, port = rest.rpartition(":")
    if not separator or scheme not in SCHEMES or not host or not (port.isascii() and port.isdigit()) \
            or not 0 < int(port) < 65536:
        raise UserError(f"--scheduler expects tcp://HOST:PORT, got '{address}'")


def _check_folder(out: Path) -> Path:
    folder = out.absolute()
    if folder.exists() and not folder.is_dir():
        raise UserError(f"--out {out} is a file, not a folder")
    parent = folder
    while not parent.exists():
        parent = parent.parent
    if not os.access(parent, os.W_OK):
        raise UserError(f"--out {out}: folder {parent} is not writable")
    return folder


def _base(path: Path | None) -> dict[str, Any] | None:
    return None if path is None else config_module.read_toml(path)


def _run_keys(args: argparse.Namespace) -> dict[str, Any]:
    """--duration and the gait: --gait, else the --config file's, else the tripod as `testbed bench`
    walks it (at the config's speed)."""
    configured = (_base(args.config) or {}).get("run", {}).get("gait")
    gait = args.gait if args.gait is not None else None if configured is not None else DEFAULT_GAIT
    return {key: value for key, value in (("duration", args.duration), ("gait", gait)) if value is not None}


def _grid(args: argparse.Namespace) -> list[sweep.GridPoint]:
    defaults = config_module.load(args.config).run
    terrains = _specs(args.terrains or defaults.terrain, "--terrains", TERRAINS.resolve)
    estimators = _specs(args.estimators or defaults.estimator, "--estimators", resolve_estimator)
    presets = _names(args.sensors, "--sensors", "sensor preset", preset_names())
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if len(terrains) * len(seeds) * len(estimators) * len(presets) > MAX_RUNS:
        raise UserError(f"the grid has {len(terrains) * len(seeds) * len(estimators) * len(presets)} runs, "
                        f"more than {MAX_RUNS}")
    return sweep.expand_grid(terrains, seeds, estimators, presets)


def _specs(text: str, option: str, resolve) -> list[str]:
    """Comma-separated registry names or MODULE:CLASS specs, each resolved (imported) once."""
    names = [name.strip() for name in text.split(",")]
    if not all(names):
        raise UserError(f"{option} expects comma-separated names, got '{text}'")
    for name in names:
        resolve(name)
    return list(dict.fromkeys(names))


def _names(text: str, option: str, what: str, choices: Sequence[str]) -> list[str]:
    names = [name.strip() for name in text.split(",")]
    if not all(names):
        raise UserError(f"{option} expects comma-separated names, got '{text}'")
    for name in names:
        if name not in choices:
            raise UserError(f"{option}: unknown {what} '{name}' (choose from {', '.join(choices)})")
    return list(dict.fromkeys(names))


# --- running ---------------------------------------------------------------------------------

def _backend(args: argparse.Namespace, pending: int):
    if args.scheduler is None:
        return sweep.LocalPool(min(args.workers or os.cpu_count() or 1, pending))
    client = sweep.connect(args.scheduler, args.connect_timeout)
    if not client.scheduler_info().get("workers"):
        print(f"testbed: warning: the scheduler at {args.scheduler} has no workers yet; the runs wait "
              f"{args.connect_timeout:g} s (--connect-timeout) for one", file=sys.stderr)
    return sweep.DaskPool(client, args.max_attempts, patience=args.connect_timeout)


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """One sweep at a time per folder (an advisory lock on the folder itself: nothing is written)."""
    handle = os.open(folder, os.O_RDONLY)
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"{folder} is in use by another sweep") from None
        yield
    finally:
        os.close(handle)


def _run(todo, index, backend, total: int, max_attempts: int) -> sweep.Summary:
    from tqdm import tqdm

    with tqdm(total=total, initial=total - len(todo), desc="sweep", unit="run", file=sys.stderr,
              dynamic_ncols=True, smoothing=0) as bar:
        return sweep.run_sweep(todo, index, backend, total, max_attempts, bar)


def _warn_unseen(folder: Path, index: sweep.Index, todo) -> None:
    """Cluster workers write the MCAP files themselves: say so when this machine cannot see them."""
    unseen = [spec.name for spec in todo if spec.name in index.rows and not Path(spec.path).exists()]
    if unseen:
        print(f"testbed: warning: {len(unseen)} finished runs are not visible here (e.g. {unseen[0]}.mcap): "
              f"the workers must write to a folder this machine shares ({folder})", file=sys.stderr)


def _report(summary: sweep.Summary, folder: Path, wall: float) -> int:
    done = summary.skipped + summary.executed
    print(f"sweep: {done} of {_runs(summary.total)} done in {folder} ({summary.executed} run now, "
          f"{summary.skipped} before; {summary.retried} retried, {len(summary.failed)} failed) in {wall:.1f} s; "
          f"index {folder / sweep.INDEX_FILE}")
    if summary.interrupted:
        print(f"testbed: sweep interrupted with {done} of {_runs(summary.total)} done; "
              "run the same command again to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    if summary.failed:
        print(f"testbed: {_runs(len(summary.failed))} failed ({', '.join(summary.failed[:5])}"
              f"{', ...' if len(summary.failed) > 5 else ''}); run the same command again to retry them",
              file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _runs(count: int) -> str:
    return f"{count} run" if count == 1 else f"{count} runs"
