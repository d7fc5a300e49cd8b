"""`testbed locobench`: the locomotion benchmark's options, its runs, its report."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from testbed.model.errors import UserError
from testbed.runtime.outputs import prepare_folder
from testbed.tools import locobench, locobench_report
from testbed.tools.locobench import CACHE, CONTACTS, GAITS, LAYOUTS, LONG_SCENARIOS, LocoSet, run_cases


def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser("locobench", help="the locomotion benchmark: courses, gaits, contact models, "
                                                     "long walks; EKF + posture controller")
    parser.add_argument("--seeds", type=int, default=10, metavar="N", help="seeds per course layout (default 10)")
    parser.add_argument("--layouts", default=",".join(LAYOUTS), metavar="L1,L2",
                        help=f"course layouts (default {','.join(LAYOUTS)}; none: no course runs)")
    parser.add_argument("--gaits", default=",".join(GAITS), metavar="G1,G2", help=f"default {','.join(GAITS)}")
    parser.add_argument("--contacts", default=",".join(CONTACTS), metavar="C1,C2",
                        help=f"default {','.join(CONTACTS)}")
    parser.add_argument("--long", default="all", metavar="W1,W2",
                        help=f"long walks: {', '.join(LONG_SCENARIOS)}, all (default) or none")
    parser.add_argument("--long-duration", type=float, default=locobench.LONG_DURATION, metavar="SECONDS",
                        help=f"simulated seconds of each long walk (default {locobench.LONG_DURATION:g})")
    parser.add_argument("--max-duration", type=float, metavar="SECONDS",
                        help="cut the course runs at this many simulated seconds (a quick look; no target is reached)")
    parser.add_argument("--config", type=Path, metavar="FILE",
                        help="TOML file overriding testbed/defaults.toml in every case (part of the cache key)")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help="processes (default 2)")
    parser.add_argument("--cache", type=Path, default=CACHE, metavar="DIR",
                        help=f"the runs' metrics JSON (default {CACHE})")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", type=Path, metavar="DIR", help="write locomotion.md, locomotion.csv and the plots here")
    where.add_argument("--docs", action="store_true",
                       help="write docs/results/locomotion.{md,csv} and docs/img/locomotion_*.png, then docs/results.md")
    parser.set_defaults(handler=cmd_locobench)


def _names(text: str, option: str, allowed: Sequence[str], none_allowed: bool = False) -> tuple[str, ...]:
    if none_allowed and text.strip() == "none":
        return ()
    names = tuple(dict.fromkeys(name.strip() for name in text.split(",") if name.strip()))
    if not names:
        raise UserError(f"{option} is empty")
    unknown = [name for name in names if name not in allowed]
    if unknown:
        raise UserError(f"{option}: unknown '{unknown[0]}' (choose from {', '.join(allowed)})")
    return names


def loco_set_from_args(args: argparse.Namespace) -> LocoSet:
    if not 1 <= args.seeds <= 1000:
        raise UserError(f"--seeds must be 1 ... 1000, got {args.seeds}")
    if not 10.0 <= args.long_duration <= 3600.0:
        raise UserError(f"--long-duration must be 10 ... 3600 s, got {args.long_duration:g}")
    if args.max_duration is not None and not 5.0 <= args.max_duration <= 3600.0:
        raise UserError(f"--max-duration must be 5 ... 3600 s, got {args.max_duration:g}")
    if not 1 <= args.workers <= 1024:
        raise UserError(f"--workers must be 1 ... 1024, got {args.workers}")
    long = tuple(LONG_SCENARIOS) if args.long.strip() == "all" else \
        _names(args.long, "--long", tuple(LONG_SCENARIOS), none_allowed=True)
    loco_set = LocoSet(args.seeds, _names(args.layouts, "--layouts", tuple(LAYOUTS), none_allowed=True),
                       _names(args.gaits, "--gaits", GAITS), _names(args.contacts, "--contacts", CONTACTS),
                       long, args.long_duration, args.max_duration, args.config)
    if not loco_set.layouts and not loco_set.long_scenarios:
        raise UserError("nothing to run: --layouts none and --long none")
    return loco_set


def cmd_locobench(args: argparse.Namespace) -> int:
    loco_set = loco_set_from_args(args)
    for folder, option in ((args.out, "--out"), (args.cache, "--cache")):
        if folder is not None and (folder.exists() and not folder.is_dir() or any(p.is_file() for p in folder.parents)):
            raise UserError(f"{option} {folder} is under a file, or a file: not a folder")
    cases = loco_set.cases()        # builds (validates) every config before any run
    if args.out is not None:
        prepare_folder(args.out, "--out")
    prepare_folder(args.cache, "--cache")
    with tqdm(total=len(cases), unit="run", desc="locobench") as bar:
        def progress(case: locobench.Case) -> None:
            bar.set_postfix_str(case.label)
            bar.update(1)
        result = run_cases(loco_set, args.cache, args.workers, progress, cases)
    if args.docs:
        locobench_report.write_docs(result)
    else:
        locobench_report.write(result, args.out)
    checks = locobench_report.target_checks(result.results)
    failed = [check for check in checks if not check.passed]
    print(f"{len(cases)} runs ({result.simulated} simulated now, the rest cached) in {result.wall_s:.0f} s; "
          f"targets met {len(checks) - len(failed)} of {len(checks)}; wrote "
          f"{'docs/results/locomotion.md' if args.docs else args.out}")
    for check in failed:
        print(f"  not met: {check.what}: {check.detail}")
    broken = [r for r in result.results if r.metrics is None]
    if broken:
        print(f"testbed: {len(broken)} run(s) gave no metrics (the report lists them), first {broken[0].case.label}: "
              f"{broken[0].failure}", file=sys.stderr)
        return 1
    return 0
