"""`testbed bench`: its options, and the run that records, replays, checks and reports."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from estimators.registry import ESTIMATORS
from testbed.model.errors import UserError
from testbed.runtime import config as config_module
from testbed.runtime.outputs import prepare_folder
from testbed.tools import bench_report
from testbed.tools.bench import (CACHE, FAULTS, ROOT, TERRAINS, Base, BenchSet, JobResult, run_bench, summary_rows,
                                 target_checks)

def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser("bench", help="estimator-accuracy benchmark: replay estimators over recorded walks")
    parser.add_argument("--terrains", default=",".join(TERRAINS), metavar="T1,T2",
                        help=f"terrains (default {','.join(TERRAINS)})")
    parser.add_argument("--estimators", default=",".join(ESTIMATORS.names()), metavar="E1,E2",
                        help=f"estimators (default all: {','.join(ESTIMATORS.names())}; or MODULE:CLASS)")
    parser.add_argument("--seeds", type=int, default=10, metavar="N", help="seeds per terrain (default 10)")
    parser.add_argument("--first-seed", type=int, default=0, metavar="S", help="seeds S ... S+N-1 (default 0)")
    parser.add_argument("--duration", type=float, default=20.0, metavar="SECONDS",
                        help="simulated seconds per walk (default 20)")
    parser.add_argument("--faults", default="none", metavar="F1,F2",
                        help=f"also replay with sensor faults: {', '.join(FAULTS[1:])} or all (default none)")
    parser.add_argument("--sensors", metavar="PRESET", help="sensor preset (testbed/presets/*.toml)")
    parser.add_argument("--config", type=Path, help="TOML file overriding testbed/defaults.toml")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help="processes (default 2)")
    parser.add_argument("--cache", type=Path, default=CACHE, metavar="DIR",
                        help=f"dataset cache (default {CACHE}, the user's cache folder)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR",
                        help="write results.md, results.csv, results.json and the plots here")
    parser.set_defaults(handler=cmd_bench)


def _names(text: str, option: str, allowed: Sequence[str]) -> tuple[str, ...]:
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if not names:
        raise UserError(f"{option} is empty")
    unknown = [name for name in names if name not in allowed]
    if unknown:
        raise UserError(f"{option}: unknown '{unknown[0]}' (choose from {', '.join(allowed)})")
    return tuple(dict.fromkeys(names))


def bench_set_from_args(args: argparse.Namespace) -> BenchSet:
    terrains = _names(args.terrains, "--terrains", TERRAINS)
    estimators = tuple(dict.fromkeys(name.strip() for name in args.estimators.split(",") if name.strip()))
    if not estimators:
        raise UserError("--estimators: give at least one estimator")
    for spec in estimators:
        ESTIMATORS.resolve(spec)
    faults = () if args.faults == "none" else FAULTS[1:] if args.faults == "all" else \
        _names(args.faults, "--faults", FAULTS[1:])
    if args.seeds < 1:
        raise UserError(f"--seeds must be at least 1, got {args.seeds}")
    if args.seeds > 10_000:
        raise UserError(f"--seeds must be at most 10000, got {args.seeds}")
    if not 0 <= args.first_seed < 2**62:
        raise UserError(f"--first-seed must be 0 ... 2^62, got {args.first_seed}")
    if not 2.0 <= args.duration <= 3600.0:
        raise UserError(f"--duration must be at least 2 s (the first second is not scored), got {args.duration}")
    if not 1 <= args.workers <= 1024:
        raise UserError(f"--workers must be 1 ... 1024, got {args.workers}")
    seeds = tuple(range(args.first_seed, args.first_seed + args.seeds))
    fault_estimators = tuple(name for name in estimators if name != "ukf") or estimators
    return BenchSet(terrains, seeds, args.duration, estimators, faults, terrains, seeds, fault_estimators,
                    seeds[0])


def cmd_bench(args: argparse.Namespace) -> int:
    bench_set = bench_set_from_args(args)
    base = Base(config_module.read_toml(args.config) if args.config is not None else None, args.sensors)
    for folder, option in ((args.out, "--out"), (args.cache, "--cache")):
        if folder.exists() and not folder.is_dir() or any(parent.is_file() for parent in folder.parents):
            raise UserError(f"{option} {folder} is under a file, or a file: not a folder")
    jobs = len(bench_set.jobs(base, args.cache))    # builds (validates) every config before any run
    prepare_folder(args.out, "--out")
    prepare_folder(args.cache, "--cache")
    with tqdm(total=jobs, unit="walk", desc="bench") as bar:
        def progress(result: JobResult) -> None:
            bar.set_postfix_str(result.replays[0].scenario.label if result.replays else "")
            bar.update(1)
        result = run_bench(bench_set, base, args.cache, args.workers, progress)
    checks = target_checks(summary_rows(result.replays), anees_per_terrain=len(bench_set.seeds) >= 10)
    bench_report.write(result, checks, args.out)
    failed = [check for check in checks if not check.passed]
    print(f"{len(result.replays)} replays of {jobs} walks ({result.recorded} simulated, the rest cached) in "
          f"{result.wall_s:.0f} s; targets met {len(checks) - len(failed)} of {len(checks)}; wrote {args.out}")
    for check in failed:
        print(f"  not met: {check.what}: {check.detail}")
    return 0
