"""`testbed bench`: its options, and the run that records, replays, checks and reports.

The defaults are the full set of `make bench` (`testbed.tools.bench.BenchSet()`); every axis can be
narrowed for development (`--terrains flat --contacts dart --grades default --seeds 2
--duration 10`). `make bench` takes the same options from the environment variable BENCH_ARGS.
"""

from __future__ import annotations

import argparse
import math
import shlex
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from estimators.registry import ESTIMATORS
from testbed.model.errors import UserError
from testbed.runtime import config as config_module
from testbed.runtime.outputs import prepare_folder
from testbed.runtime.presets import preset_names
from testbed.tools import bench_report
from testbed.tools.bench import (ARRAYS, CACHE, CONTACTS, FAULTS, TERRAINS, Base, BenchSet, JobResult, cached_walks,
                                 run_bench, summary_rows, target_checks)

FULL = BenchSet()


def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser("bench", help="estimator-accuracy benchmark: replay estimators over recorded walks")
    add_set_options(parser)
    parser.add_argument("--config", type=Path, help="TOML file overriding testbed/defaults.toml")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help="processes (default 2)")
    parser.add_argument("--cache", type=Path, default=CACHE, metavar="DIR",
                        help=f"dataset cache (default {CACHE}, the user's cache folder)")
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="write results.md, results.csv, results.json and the plots here")
    parser.add_argument("--docs", action="store_true",
                        help="also refresh docs/results.md, docs/results/estimators.* and docs/img/estimators_*.png")
    parser.set_defaults(handler=cmd_bench)


def add_set_options(parser: argparse.ArgumentParser) -> None:
    """The options that choose the bench set, defaulting to the full set."""
    def listed(values: Sequence) -> str:
        return ",".join(str(value) for value in values) or "none"

    parser.add_argument("--terrains", default=listed(FULL.terrains), metavar="T1,T2",
                        help=f"terrains (default {listed(FULL.terrains)})")
    parser.add_argument("--contacts", default=listed(FULL.contacts), metavar="C1,C2",
                        help=f"contact models (default {listed(FULL.contacts)})")
    parser.add_argument("--grades", "--sensors", default=listed(FULL.grades), metavar="P1,P2",
                        help=f"IMU grades: sensor presets, testbed/presets/*.toml (default {listed(FULL.grades)})")
    parser.add_argument("--estimators", default=listed(FULL.estimators), metavar="E1,E2",
                        help=f"estimators (default all: {listed(FULL.estimators)}; or MODULE:CLASS)")
    parser.add_argument("--seeds", type=int, default=len(FULL.seeds), metavar="N",
                        help=f"seeds per walk set (default {len(FULL.seeds)})")
    parser.add_argument("--first-seed", type=int, default=0, metavar="S", help="seeds S ... S+N-1 (default 0)")
    parser.add_argument("--duration", type=float, default=FULL.duration, metavar="SECONDS",
                        help=f"simulated seconds per walk (default {FULL.duration:g})")
    parser.add_argument("--array-terrains", default=listed(FULL.array_terrains), metavar="T1,T2",
                        help=f"also walk these terrains with the quad accelerometer array, default grade "
                             f"(default {listed(FULL.array_terrains)}; none)")
    parser.add_argument("--faults", default=listed(FULL.faults), metavar="F1,F2",
                        help=f"sensor faults: {', '.join(FAULTS[1:])}, all or none (default {listed(FULL.faults)})")
    parser.add_argument("--fault-terrains", default=listed(FULL.fault_terrains), metavar="T1,T2",
                        help=f"terrains of the fault walks (default {listed(FULL.fault_terrains)})")
    parser.add_argument("--fault-array", default=FULL.fault_array, choices=ARRAYS,
                        help=f"accelerometer array of the fault walks (default {FULL.fault_array})")


def _names(text: str, option: str, allowed: Sequence[str], empty: bool = False) -> tuple[str, ...]:
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if names == ("none",) and empty:
        return ()
    if not names:
        raise UserError(f"{option} is empty")
    unknown = [name for name in names if name not in allowed]
    if unknown:
        raise UserError(f"{option}: unknown '{unknown[0]}' (choose from {', '.join(allowed)})")
    return tuple(dict.fromkeys(names))


def bench_set_from_args(args: argparse.Namespace) -> BenchSet:
    terrains = _names(args.terrains, "--terrains", TERRAINS)
    contacts = _names(args.contacts, "--contacts", CONTACTS)
    grades = _grades(args.grades)
    estimators = tuple(dict.fromkeys(name.strip() for name in args.estimators.split(",") if name.strip()))
    if not estimators:
        raise UserError("--estimators: give at least one estimator")
    for spec in estimators:
        ESTIMATORS.resolve(spec)
    faults = FAULTS[1:] if args.faults == "all" else _names(args.faults, "--faults", FAULTS[1:], empty=True)
    if args.seeds < 1:
        raise UserError(f"--seeds must be at least 1, got {args.seeds}")
    if args.seeds > 10_000:
        raise UserError(f"--seeds must be at most 10000, got {args.seeds}")
    if not 0 <= args.first_seed < 2**62:
        raise UserError(f"--first-seed must be 0 ... 2^62, got {args.first_seed}")
    if not (math.isfinite(args.duration) and 2.0 <= args.duration <= 3600.0):
        raise UserError(f"--duration must be at least 2 s (the first second is not scored), got {args.duration}")
    seeds = tuple(range(args.first_seed, args.first_seed + args.seeds))
    fault_estimators = tuple(name for name in estimators if name != "ukf") or estimators
    return BenchSet(terrains, contacts, grades, seeds, args.duration, estimators,
                    _names(args.array_terrains, "--array-terrains", TERRAINS, empty=True), faults,
                    _names(args.fault_terrains, "--fault-terrains", TERRAINS), seeds, fault_estimators,
                    args.fault_array, seeds[0])


def _grades(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(name.strip() for name in text.split(",") if name.strip()))
    if not names:
        raise UserError("--grades is empty")
    unknown = [name for name in names if name not in preset_names()]
    if unknown:
        raise UserError(f"unknown sensor preset '{unknown[0]}' (choose from {', '.join(preset_names())})")
    return names


def bench_set_from_text(text: str) -> BenchSet:
    """The bench set of options given as one string (BENCH_ARGS of `make bench`); the full set for ''."""
    parser = argparse.ArgumentParser(prog="BENCH_ARGS", add_help=False, exit_on_error=False)
    add_set_options(parser)
    try:
        args, unknown = parser.parse_known_args(shlex.split(text))
    except (argparse.ArgumentError, ValueError) as error:
        raise UserError(f"BENCH_ARGS: {error}") from None
    if unknown:
        raise UserError(f"BENCH_ARGS: unknown option '{unknown[0]}'")
    return bench_set_from_args(args)


def cmd_bench(args: argparse.Namespace) -> int:
    bench_set = bench_set_from_args(args)
    if not 1 <= args.workers <= 1024:
        raise UserError(f"--workers must be 1 ... 1024, got {args.workers}")
    if args.out is None and not args.docs:
        raise UserError("give --out DIR, --docs or both: where to write the results")
    base = Base(config_module.read_toml(args.config) if args.config is not None else None)
    folders = ((args.out, "--out"), (args.cache, "--cache")) if args.out is not None else ((args.cache, "--cache"),)
    for folder, option in folders:
        if folder.exists() and not folder.is_dir() or any(parent.is_file() for parent in folder.parents):
            raise UserError(f"{option} {folder} is under a file, or a file: not a folder")
    jobs = bench_set.jobs(base, args.cache)    # builds (validates) every config before any run
    if args.out is not None:
        prepare_folder(args.out, "--out")
    prepare_folder(args.cache, "--cache")
    cached = cached_walks(jobs)
    print(f"{len(jobs)} walks ({cached} in the cache, {len(jobs) - cached} to simulate), "
          f"{sum(len(job.estimators) for job in jobs)} replays on {args.workers} workers")
    with tqdm(total=len(jobs), unit="walk", desc="bench") as bar:
        def progress(result: JobResult) -> None:
            bar.set_postfix_str(result.scenario.label)
            bar.update(1)
        result = run_bench(bench_set, base, args.cache, args.workers, progress)
    checks = target_checks(summary_rows(result.replays))
    if args.out is not None:
        bench_report.write(result, checks, args.out)
    if args.docs:
        bench_report.write_docs(result, checks)
    measured = [check for check in checks if check.passed is not None]
    failed = [check for check in measured if not check.passed]
    print(f"{len(result.replays)} replays of {len(jobs)} walks ({result.recorded} simulated, the rest cached) in "
          f"{result.wall_s:.0f} s; targets met {len(measured) - len(failed)} of {len(measured)} measured "
          f"({len(checks) - len(measured)} not measured); wrote {args.out or ''}"
          f"{' and ' if args.out and args.docs else ''}{'docs/results.md' if args.docs else ''}")
    for note in result.failed:
        print(f"  not recorded: {note}")
    for check in failed:
        print(f"  not met: {check.what}: {check.detail}")
    return 0
