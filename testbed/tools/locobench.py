"""Locomotion benchmark (issue 21): the EKF and the posture controller walking to a target across
courses of ramps, steps, stairs and rough patches with every gait and both contact models, and long
walks on flat ground and on a course of ramps; the figures come from each run's metrics alone.

A case is one run. Its terrain parameters and its `run.seed` are drawn from a numpy Generator seeded
by the case's identity (`BENCH_SEED`, the layout or long scenario, the seed index), so the terrains
are none that a controller was tuned on, and the same seed index gives the same course to every gait
and contact model. Each case's metrics are cached as JSON (the `testbed run --metrics` format plus
`error`) under a hash of its config and of the source of the simulation (testbed but its tools,
sensors, estimators): a changed controller runs again, the same code reads the cache.
`locobench_report` writes the tables and the plots from these JSON files.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from testbed.runtime import config as config_module
from testbed.runtime.metrics import write_metrics
from testbed.tools.bench_report import load_average

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(platformdirs.user_cache_dir("hexapod-testbed")) / "locobench"
SIMULATION_SOURCES = ("testbed", "sensors", "estimators")      # their source is part of a case's cache key
NOT_SIMULATION = ("tools",)                                    # testbed/tools: reporting, not simulation
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
WAKE_PERIOD = 0.5               # s, the longest the benchmark's process waits without looking at Ctrl-C
BENCH_SEED = 21_2026            # root of every case's Generator; not a seed anything was tuned on

COURSES, LONG = "courses", "long"
GAITS = ("tripod", "ripple", "wave")
CONTACTS = ("compliant", "dart")
SPEEDS = {"tripod": 0.1, "ripple": 0.06, "wave": 0.04}        # m/s: a 5 cm stride at each gait's default period

# Course layouts: the features in walking order, each with its direction (+1 up, -1 down).
LAYOUTS = {
    "A": (("ramp", 1), ("step", -1), ("stairs", 1), ("rough", 0)),
    "B": (("rough", 0), ("stairs", -1), ("step", 1), ("ramp", -1)),
    "C": (("step", 1), ("rough", 0), ("ramp", 1), ("stairs", -1)),
}
# The ranges the features are drawn from (uniform), m and deg.
RAMP_DEG = (12.0, 20.0)
RAMP_LENGTH = (0.4, 0.7)
STEP_HEIGHT = (0.03, 0.06)
STAIR_RISE = (0.03, 0.05)
STAIR_STEPS = (2, 4)
STAIR_TREAD = (0.15, 0.25)
ROUGH_AMPLITUDE = (0.025, 0.035)
ROUGH_LENGTH = (0.5, 0.8)
ROUGH_CELL = (0.08, 0.12)
GAP = (0.4, 0.6)                # level ground between two features
COURSE_START = -0.5             # m: the course's first segment starts here
LEAD = 0.8                      # m of level ground first: the first feature starts 0.3 m ahead of the body
TARGET_BEYOND = 0.5             # m: the target lies this far beyond the last feature, every foot past it
WIDTH = 1.5                     # m: the courses span y = -WIDTH ... WIDTH
LONG_WIDTH = 0.25               # of the length: the long walks' ground is this wide to each side (no heading control)
DURATION_MARGIN = 1.6           # course runs end 2 s after arrival, at the latest after the walk at the commanded
                                # speed times this, plus 3 s: time to arrive for the slower gaits, whose clock
                                # waits for the ground at every step down
LONG_DURATION = 600.0           # s
LONG_SCENARIOS = {              # name: (terrain, speed m/s, tripod period s)
    "flat 0.1 m/s": ("flat", 0.1, 1.0),
    "flat 0.2 m/s": ("flat", 0.2, 0.5),          # the period halved: the same 5 cm stride
    "ramps 0.1 m/s": ("course", 0.1, 1.0),
}
LONG_RAMP_LENGTH = (1.0, 2.0)   # m, the long course's up ramps; a down ramp returns to the level before


@dataclass
class Case:
    group: str                  # COURSES or LONG
    scenario: str               # the table row it belongs to: "A tripod compliant", "flat 0.1 m/s"
    index: int                  # which of the scenario's seeds
    config: dict[str, Any]      # the resolved config (Config.to_dict())
    terrain: str                # the drawn features, for the tables

    @property
    def label(self) -> str:
        return f"{self.scenario} #{self.index}"

    @property
    def key(self) -> str:
        text = json.dumps(self.config, sort_keys=True) + source_digest()
        return hashlib.sha256(text.encode()).hexdigest()[:20]


@cache
def source_digest() -> str:
    """sha256 of every Python and TOML file that shapes a run: testbed (but its tools), sensors, estimators."""
    digest = hashlib.sha256()
    for package in SIMULATION_SOURCES:
        folder = ROOT / package
        for path in sorted(folder.rglob("*")):
            relative = path.relative_to(folder)
            if path.suffix in (".py", ".toml") and "__pycache__" not in relative.parts and \
                    not (package == "testbed" and relative.parts[0] in NOT_SIMULATION):
                digest.update(str(relative).encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


# --- drawing the terrains --------------------------------------------------------------------

def generator(*identity: int | str) -> np.random.Generator:
    """The Generator of one case: BENCH_SEED and the case's identity (names hashed to integers)."""
    words = [int.from_bytes(hashlib.sha256(str(part).encode()).digest()[:4], "little") for part in identity]
    return np.random.default_rng([BENCH_SEED, *words])


def _uniform(rng: np.random.Generator, bounds: tuple[float, float], digits: int = 3) -> float:
    return round(float(rng.uniform(*bounds)), digits)


def feature(rng: np.random.Generator, kind: str, direction: int) -> dict[str, Any]:
    """One course segment of `kind` with its parameters drawn from their ranges."""
    if kind == "ramp":
        return {"kind": "ramp", "length": _uniform(rng, RAMP_LENGTH), "angle_deg": direction * _uniform(rng, RAMP_DEG, 1)}
    if kind == "step":
        return {"kind": "step", "height": direction * _uniform(rng, STEP_HEIGHT)}
    if kind == "stairs":
        return {"kind": "stairs", "steps": int(rng.integers(STAIR_STEPS[0], STAIR_STEPS[1] + 1)),
                "rise": direction * _uniform(rng, STAIR_RISE), "tread": _uniform(rng, STAIR_TREAD)}
    if kind == "rough":
        return {"kind": "rough", "length": _uniform(rng, ROUGH_LENGTH), "amplitude": _uniform(rng, ROUGH_AMPLITUDE),
                "cell": _uniform(rng, ROUGH_CELL)}
    raise ValueError(f"unknown feature kind {kind!r}")


def layout_text(layout: str) -> str:
    """`ramp up, step down, stairs up, rough`."""
    return ", ".join(kind + {1: " up", -1: " down", 0: ""}[direction] for kind, direction in LAYOUTS[layout])


def segment_length(segment: dict[str, Any]) -> float:
    """Its extent along x, m."""
    if segment["kind"] == "stairs":
        return segment["steps"] * segment["tread"]
    return segment.get("length", 0.0)


def describe(segment: dict[str, Any]) -> str:
    """`ramp +15.2° 0.52 m`, `step -4.1 cm`, `stairs 3 x +3.6 cm / 18 cm`, `rough ±2.9 cm`."""
    kind = segment["kind"]
    if kind == "ramp":
        return f"ramp {segment['angle_deg']:+.1f}° {segment['length']:.2f} m"
    if kind == "step":
        return f"step {segment['height'] * 100:+.1f} cm"
    if kind == "stairs":
        return f"stairs {segment['steps']} x {segment['rise'] * 100:+.1f} cm / {segment['tread'] * 100:.0f} cm"
    if kind == "rough":
        return f"rough ±{segment['amplitude'] * 100:.1f} cm"
    return f"{kind} {segment_length(segment):.2f} m"


def layout_course(layout: str, index: int) -> tuple[list[dict[str, Any]], float]:
    """The course of `layout`'s seed `index` (its features between level gaps) and the target's x."""
    rng = generator(COURSES, layout, index)
    segments: list[dict[str, Any]] = [{"kind": "flat", "length": LEAD}]
    for number, (kind, direction) in enumerate(LAYOUTS[layout]):
        if number:
            segments.append({"kind": "flat", "length": _uniform(rng, GAP)})
        segments.append(feature(rng, kind, direction))
    end = COURSE_START + sum(segment_length(s) for s in segments)
    segments.append({"kind": "flat", "length": TARGET_BEYOND + 0.5})
    return segments, round(end + TARGET_BEYOND, 3)


def ramp_course(rng: np.random.Generator, length: float) -> list[dict[str, Any]]:
    """Level ground, a ramp up, level ground, a ramp down to the level before, ... for `length` m."""
    segments: list[dict[str, Any]] = [{"kind": "flat", "length": LEAD}]
    while COURSE_START + sum(segment_length(s) for s in segments) < length:
        up_deg, down_deg = _uniform(rng, RAMP_DEG, 1), _uniform(rng, RAMP_DEG, 1)
        up = _uniform(rng, LONG_RAMP_LENGTH)
        down = round(up * math.tan(math.radians(up_deg)) / math.tan(math.radians(down_deg)), 3)
        segments += [{"kind": "ramp", "length": up, "angle_deg": up_deg}, {"kind": "flat", "length": 1.0},
                     {"kind": "ramp", "length": down, "angle_deg": -down_deg}, {"kind": "flat", "length": 1.0}]
    return segments


# --- the cases -------------------------------------------------------------------------------

@dataclass(frozen=True)
class LocoSet:
    """What to run: every layout x seed x gait x contact walking to its target, and the long walks."""
    seeds: int = 10
    layouts: tuple[str, ...] = tuple(LAYOUTS)
    gaits: tuple[str, ...] = GAITS
    contacts: tuple[str, ...] = CONTACTS
    long_scenarios: tuple[str, ...] = tuple(LONG_SCENARIOS)
    long_duration: float = LONG_DURATION            # s
    max_duration: float | None = None               # s, cuts the course runs short (smoke tests)
    config_file: Path | None = None                 # TOML overriding testbed/defaults.toml in every case

    @property
    def full(self) -> bool:
        return self == LocoSet()

    def cases_of_courses(self) -> list[tuple[str, int, str, str]]:
        """(layout, seed index, gait, contact) of every course run."""
        return [(layout, index, gait, contact) for layout in self.layouts for index in range(self.seeds)
                for gait in self.gaits for contact in self.contacts]

    def base(self) -> dict[str, Any] | None:
        """The overrides of `config_file` (read and parsed here), or None."""
        return config_module.read_toml(self.config_file) if self.config_file is not None else None

    def cases(self) -> list[Case]:
        """Every case, its config built (validated) here."""
        base = self.base()
        cases = [course_case(*identity, self.max_duration, base) for identity in self.cases_of_courses()]
        return cases + [long_case(name, self.long_duration, base) for name in self.long_scenarios]


def _config(overrides: dict[str, Any], base: dict[str, Any] | None = None) -> dict[str, Any]:
    """Defaults, then `base` (a user's config file), then `overrides`, with the EKF and the posture
    controller; validated."""
    overrides["run"].update(estimator="ekf", controller="posture")
    return config_module.load(None, overrides, base=base).to_dict()


def course_case(layout: str, index: int, gait: str, contact: str, max_duration: float | None = None,
                base: dict[str, Any] | None = None) -> Case:
    """Walk to the target beyond `layout`'s course of seed `index`; the run ends once the robot
    stopped there (`gait.end_at_arrival`), at the latest after `duration`."""
    segments, target_x = layout_course(layout, index)
    seed = int(generator(COURSES, layout, index, "run").integers(2**31))
    speed = SPEEDS[gait]
    probe = config_module.load(None, {"run": {"gait": gait}, "gait": {"speed": speed}}, base=base)
    duration = probe.gait.duration_to_walk(probe.gait.start_ramp + DURATION_MARGIN * target_x / speed + 3.0)
    duration = round(min(duration, max_duration) if max_duration else duration, 1)
    overrides = {"run": {"terrain": "course", "gait": gait, "contact": contact, "seed": seed, "duration": duration},
                 "gait": {"speed": speed, "target": [target_x, 0.0], "end_at_arrival": True},
                 "terrain": {"course": segments, "course_start": COURSE_START,
                             "extent": [-2.0, round(target_x + 1.0, 3), -WIDTH, WIDTH]}}
    features = [describe(s) for s in segments if s["kind"] != "flat"]
    return Case(COURSES, f"{layout} {gait} {contact}", index, _config(overrides, base), " | ".join(features))


def long_case(name: str, duration: float = LONG_DURATION, base: dict[str, Any] | None = None) -> Case:
    """A long tripod walk (compliant contact) on flat ground or on a course of ramps."""
    terrain, speed, period = LONG_SCENARIOS[name]
    rng = generator(LONG, name)
    seed = int(rng.integers(2**31))
    reach = round(speed * duration + 2.0, 1)         # m walked, and the feet ahead of the body
    side = round(max(WIDTH, LONG_WIDTH * reach), 1)
    overrides: dict[str, Any] = {
        "run": {"terrain": terrain, "gait": "tripod", "contact": "compliant", "seed": seed, "duration": duration},
        "gait": {"speed": speed, "tripod_period": period},
        "terrain": {"extent": [-2.0, reach, -side, side]}}
    description = f"flat, {reach + 2.0:.0f} m x {2 * side:.0f} m"
    if terrain == "course":
        segments = ramp_course(rng, reach - 1.0)
        end = COURSE_START + sum(segment_length(s) for s in segments)
        overrides["terrain"].update(course=segments, course_start=COURSE_START,
                                    extent=[-2.0, round(end + 1.0, 3), -side, side])
        ramps = [s["angle_deg"] for s in segments if s["kind"] == "ramp"]
        description = (f"{len(ramps)} ramps of {min(abs(a) for a in ramps):.1f}-{max(abs(a) for a in ramps):.1f}°, "
                       f"up and down, over {end - COURSE_START:.0f} m")
    return Case(LONG, name, 0, _config(overrides, base), description)


# --- running them ----------------------------------------------------------------------------

@dataclass
class CaseResult:
    case: Case
    metrics: dict[str, Any] | None      # the run's metrics JSON; None when the run could not be done
    failure: str | None = None          # why not


@dataclass
class LocoResult:
    loco_set: LocoSet
    results: list[CaseResult]
    wall_s: float
    simulated: int                      # runs done now (the others came from the cache)
    workers: int
    load_before: float = float("nan")


def metrics_path(case: Case, cache_dir: Path) -> Path:
    return Path(cache_dir) / f"{case.key}.json"


def simulate(config: dict[str, Any], path: str) -> None:
    """Run one case and write its metrics JSON (with `error`: why the run stopped early, or null);
    an interrupted run writes nothing."""
    from testbed.runtime.runner import run

    outcome = run(config_module.from_dict(config))
    if outcome.interrupted:
        raise KeyboardInterrupt(outcome.error)
    write_metrics(path, {**outcome.metrics, "error": outcome.error})


def _ignore_sigint() -> None:
    """Ctrl-C reaches the whole process group; the benchmark's own process alone decides what stops."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_cases(loco_set: LocoSet, cache_dir: Path = CACHE, workers: int = 2,
              progress: Callable[[Case], None] | None = None, cases: Sequence[Case] | None = None) -> LocoResult:
    """Every case not in the cache on `workers` processes (1: in this process), then every case's
    metrics read back from its JSON file."""
    cases = list(cases) if cases is not None else loco_set.cases()
    load = load_average()
    started = time.perf_counter()
    todo = [case for case in cases if not metrics_path(case, cache_dir).exists()]
    for case in cases:
        if case not in todo and progress:
            progress(case)
    failures = _run(todo, Path(cache_dir), workers, progress)
    results = [read_result(case, cache_dir, failures.get(case.label)) for case in cases]
    return LocoResult(loco_set, results, time.perf_counter() - started, len(todo) - len(failures), workers, load)


def read_result(case: Case, cache_dir: Path, failure: str | None = None) -> CaseResult:
    path = metrics_path(case, cache_dir)
    if failure is not None or not path.exists():
        return CaseResult(case, None, failure or "no metrics written")
    return CaseResult(case, json.loads(path.read_text(encoding="utf-8")))


def _run(todo: Sequence[Case], cache_dir: Path, workers: int, progress: Callable[[Case], None] | None) -> dict[str, str]:
    """Simulate `todo`; the failures, label -> one line."""
    cache_dir.mkdir(parents=True, exist_ok=True)
    failures: dict[str, str] = {}
    if workers <= 1:
        for case in todo:
            try:
                simulate(case.config, str(metrics_path(case, cache_dir)))
            except Exception as error:      # noqa: BLE001 - one case's failure is reported, the others go on
                failures[case.label] = f"{type(error).__name__}: {error}"
            if progress:
                progress(case)
        return failures
    for name in THREAD_VARIABLES:       # one thread per worker: the workers are the parallelism
        os.environ.setdefault(name, "1")
    # The longest runs first, so that the last ones running are short.
    order = sorted(todo, key=lambda case: -case.config["run"]["duration"])
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_sigint)
    try:
        futures = {pool.submit(simulate, case.config, str(metrics_path(case, cache_dir))): case for case in order}
        pending = set(futures)
        while pending:
            # A timeout: the main thread wakes to take a Ctrl-C that the OS handed to another thread.
            finished, pending = wait(pending, timeout=WAKE_PERIOD, return_when=FIRST_COMPLETED)
            for future in finished:
                case = futures[future]
                try:
                    future.result()
                except Exception as error:      # noqa: BLE001 - one case's failure is reported, the others go on
                    failures[case.label] = f"{type(error).__name__}: {error}"
                if progress:
                    progress(case)
    except BaseException:       # Ctrl-C: the runs in flight stop now; every finished one is in the cache
        pool.shutdown(wait=False, cancel_futures=True)
        for process in multiprocessing.active_children():
            process.terminate()
        raise
    pool.shutdown()
    return failures

