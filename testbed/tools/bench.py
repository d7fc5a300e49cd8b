"""Estimator-accuracy benchmark (issues 8 and 18): record each scenario once, replay every
estimator over the same recorded sensor data, score, check the issues' targets, report.

A scenario is a terrain, a contact model, an IMU grade (a sensor preset), an accelerometer-array
layout, a seed, a duration and an optional sensor fault, walked with the tripod gait, no
controller and no estimator (the estimators only replay). Its dataset is an MCAP file in the cache
folder named by a hash of the resolved config (without the `[estimators]` tuning, which replays do
not need) and of the source of the packages that produce the data, so that a changed simulator,
sensor model or config records again and a retuned estimator does not. Files are written under a
temporary name and renamed: a cache is never left with half a file. A walk that cannot be
recorded (the robot fell) leaves a `.failed` note in the cache, so that it is reported, not
simulated again, until the data sources change.

`testbed bench` (testbed.tools.bench_cli) and `tests/benchmarks` run the same code;
`testbed.tools.bench_report` writes the tables and plots.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import platformdirs
from typing import Any

import numpy as np

from estimators.registry import ESTIMATORS
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.runtime.presets import preset_overrides
from testbed.model.errors import UserError

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(platformdirs.user_cache_dir("hexapod-testbed")) / "bench"    # ~/.cache/hexapod-testbed/bench on Linux
TERRAINS = ("flat", "slope", "step", "rough", "course")
CONTACTS = ("compliant", "dart")
GRADES = ("consumer", "default", "tactical")       # sensor presets, testbed/presets/*.toml
ARRAYS = ("imu_only", "quad")                      # sensors.accel_array.layout
BASELINES = ("madgwick", "mahony", "vqf")          # the EKF must beat each of these on every row
FAULTS = ("none", "accel_spikes", "encoder_dropout", "gyro_bias_step", "gyro_stuck", "gyro_bias_jump")
GYRO_BIAS_STEP = 0.00873                            # rad/s, 0.5 deg/s on every axis
GYRO_BIAS_JUMP = 0.5                                # rad/s on the gyro's x axis
GYRO_FAULT_WINDOW = 2.0                             # s, of a stuck gyro and of the bias jump
SERIES_RATE = 100.0                                 # Hz, time series kept for the plots
# The bench's course (run.terrain = "course", docs/terrain.md), laid from x = -0.5 m so that a 30 s
# walk at 0.1 m/s (about 2.7 m) crosses each kind of segment: a 10 degree ramp up, a 3 cm step up,
# two 2 cm stairs down, a rough patch of +-1 cm blocks and an 8 degree ramp down.
COURSE = (
    {"kind": "flat", "length": 0.7},
    {"kind": "ramp", "length": 0.4, "angle_deg": 10.0},
    {"kind": "flat", "length": 0.3},
    {"kind": "step", "height": 0.03},
    {"kind": "flat", "length": 0.3},
    {"kind": "stairs", "steps": 2, "rise": -0.02, "tread": 0.2},
    {"kind": "flat", "length": 0.2},
    {"kind": "rough", "length": 0.6, "amplitude": 0.01, "cell": 0.1},
    {"kind": "flat", "length": 0.2},
    {"kind": "ramp", "length": 0.4, "angle_deg": -8.0},
    {"kind": "flat", "length": 1.0},
)
COURSE_START = -0.5                                 # m
# Packages whose source shapes a recording; their digest is part of a dataset's cache key.
DATA_SOURCES = ("testbed", "sensors", "datasets")
NOT_DATA_SOURCES = ("testbed/tools",)               # reads recordings, never shapes one
# The tables' order: the fusion filters first, then the baselines.
ESTIMATOR_ORDER = tuple(sorted(ESTIMATORS.names(), key=lambda name: (name not in ("ekf", "ukf"), name != "ekf", name)))
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


@dataclass(frozen=True)
class Scenario:
    terrain: str
    seed: int
    duration: float             # s
    fault: str = "none"         # one of FAULTS
    contact: str = "compliant"  # one of CONTACTS
    grade: str = "default"      # a sensor preset
    array: str = "imu_only"     # one of ARRAYS

    @property
    def label(self) -> str:
        parts = [self.terrain, self.contact, self.grade, f"seed {self.seed}"]
        parts += [] if self.array == "imu_only" else [f"{self.array} array"]
        return "/".join(parts + ([] if self.fault == "none" else [self.fault]))

    @property
    def reference(self) -> "Scenario":
        """The same walk without the fault."""
        return Scenario(self.terrain, self.seed, self.duration, "none", self.contact, self.grade, self.array)


def fault_specs(fault: str, duration: float) -> list[str]:
    """The sensors' fault specs (docs/sensors.md) of a fault kind, placed within a run of `duration`:
    full-scale accelerometer spikes at 20, 40, 60 and 80 % of it, from 40 % a 1 s encoder dropout,
    a 0.5 deg/s gyro bias step on every axis (to the end), a gyro stuck for 2 s, or a 0.5 rad/s
    bias on the gyro's x axis for 2 s."""
    at = round(0.4 * duration, 3)
    if fault == "none":
        return []
    if fault == "accel_spikes":
        return [f"imu.accel.spike@{round(f * duration, 3)}s" for f in (0.2, 0.4, 0.6, 0.8)]
    if fault == "encoder_dropout":
        return [f"encoder.dropout@{at}s+1s"]
    if fault == "gyro_bias_step":
        return [f"imu.gyro.bias_step@{at}s:{GYRO_BIAS_STEP}"]
    if fault == "gyro_stuck":
        return [f"imu.gyro.stuck@{at}s+{GYRO_FAULT_WINDOW:g}s"]
    if fault == "gyro_bias_jump":
        return [f"imu.gyro.x.bias_step@{at}s+{GYRO_FAULT_WINDOW:g}s:{GYRO_BIAS_JUMP}"]
    raise UserError(f"unknown fault '{fault}' (choose from {', '.join(FAULTS)})")


@dataclass(frozen=True)
class Base:
    """What a user puts under every scenario: a config file's overrides."""
    config: dict[str, Any] | None = None


def scenario_config(scenario: Scenario, base: Base = Base()) -> Config:
    """Defaults, then the user's config file, then the grade's sensor preset, then the scenario
    (the bench's course when the terrain is `course` and the user's config has none)."""
    cfg = config_module.load(None, preset_overrides(scenario.grade), base=base.config)
    faults = [*cfg.sensors.faults, *fault_specs(scenario.fault, scenario.duration)]
    terrain = {"course": list(COURSE), "course_start": COURSE_START} \
        if scenario.terrain == "course" and not cfg.terrain.course else {}
    return cfg.replace(run={"terrain": scenario.terrain, "contact": scenario.contact, "seed": scenario.seed,
                            "duration": scenario.duration, "gait": "tripod", "estimator": "none",
                            "controller": "none"},
                       sensors={"faults": faults, "accel_array": {"layout": scenario.array}}, terrain=terrain)


@cache
def source_digest() -> str:
    """sha256 of the source files that produce a recording, every module of the data packages but
    the tools (not the estimators either: they only replay). Not the TOML files: the settings they
    give are in the resolved config `dataset_key` hashes, without the estimators' tuning."""
    digest = hashlib.sha256()
    for package in DATA_SOURCES:
        for path in sorted((ROOT / package).rglob("*")):
            relative = path.relative_to(ROOT).as_posix()
            if path.suffix == ".py" and not relative.startswith(NOT_DATA_SOURCES):
                digest.update(relative.encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def dataset_key(cfg: Config) -> str:
    """Cache key of a scenario's dataset: its config without the estimator tuning, and the source."""
    data = cfg.to_dict()
    data.pop("estimators")
    data["run"]["estimator"] = "none"
    text = json.dumps(data, sort_keys=True) + source_digest()
    return hashlib.sha256(text.encode()).hexdigest()[:20]


class RecordingFailed(RuntimeError):
    """The walk could not be recorded (the robot fell, or the run stopped with an error)."""


def dataset(cfg: Config, cache_dir: Path = CACHE) -> tuple[Path, bool]:
    """The scenario's recording, simulated now unless cached: (path, recorded now). A walk that
    failed before (its `.failed` note in the cache) or fails now raises RecordingFailed."""
    path = Path(cache_dir) / f"{dataset_key(cfg)}.mcap"
    failed = path.with_suffix(".failed")
    if path.exists():
        return path, False
    if failed.exists():
        raise RecordingFailed(failed.read_text(encoding="utf-8").strip())
    from datasets.recorder import McapRecorder
    from testbed.runtime.runner import run

    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.mcap")
    try:
        outcome = run(cfg, McapRecorder(temporary))
        if outcome.error or outcome.metrics.get("fell"):
            reason = (f"{cfg.run.terrain} {cfg.run.contact} seed {cfg.run.seed}: the recording run failed "
                      f"({outcome.error or 'the robot fell'})")
            _write_note(failed, reason)
            raise RecordingFailed(reason)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
        temporary.with_name(temporary.name + ".partial").unlink(missing_ok=True)
    return path, True


def _write_note(path: Path, text: str) -> None:
    temporary = path.with_name(f".{path.name}.{os.getpid()}")
    temporary.write_text(text + "\n", encoding="utf-8")
    os.replace(temporary, path)


# --- replay and score, in a worker ---------------------------------------------------------------

@dataclass
class Series:
    """Errors of one replay over time (SERIES_RATE), for the plots."""
    t: np.ndarray
    error: np.ndarray              # (n, 2) rad, roll and pitch
    sigma: np.ndarray | None       # (n, 2) rad, from the estimator's covariance
    nees: np.ndarray | None        # (n,) of roll and pitch, every estimate averaged over 1 / SERIES_RATE


@dataclass
class ReplayResult:
    scenario: Scenario
    estimator: str
    metrics: dict[str, Any]
    cost: dict[str, dict[str, float]]      # estimators.cost.summarise
    cost_per_ms: float                     # us per simulated ms, from the medians
    cpu_per_ms: float                      # us per simulated ms, process CPU time over the whole replay
    series: Series | None = None


@dataclass(frozen=True)
class Job:
    scenario: Scenario
    config: dict[str, Any]
    estimators: tuple[str, ...]
    cache_dir: str
    keep_series: bool


@dataclass
class JobResult:
    scenario: Scenario
    replays: list[ReplayResult]
    recorded: bool
    record_s: float
    replay_s: float = 0.0
    notes: list[str] = field(default_factory=list)


def evaluate(job: Job) -> JobResult:
    """Record (or reuse) the scenario's dataset and replay every estimator over it; a walk that
    cannot be recorded gives no replays and a note."""
    from datasets.reader import REPLAY_TOPICS, read_recording

    cfg = config_module.from_dict(job.config)
    started = time.perf_counter()
    try:
        path, recorded = dataset(cfg, Path(job.cache_dir))
    except RecordingFailed as failure:
        return JobResult(job.scenario, [], False, time.perf_counter() - started, notes=[str(failure)])
    result = JobResult(job.scenario, [], recorded, time.perf_counter() - started)
    started = time.perf_counter()
    recording = read_recording(path, topics=REPLAY_TOPICS)
    samples, truth = recording.samples(), recording.scoring_truth()
    for name in job.estimators:
        result.replays.append(replay(job.scenario, cfg.replace(run={"estimator": name}), samples, truth,
                                     job.keep_series))
    result.replay_s = time.perf_counter() - started
    return result


def replay(scenario: Scenario, cfg: Config, samples: list, truth, keep_series: bool) -> ReplayResult:
    from datasets.scoring import score_run
    from estimators import cost
    from estimators.registry import make_estimator

    estimator = make_estimator(cfg.run.estimator, cfg)
    cpu = time.process_time()
    estimates, elapsed = cost.timed_run(estimator, samples)
    cpu = time.process_time() - cpu
    simulated = float(truth.t[-1] - truth.t[0])
    costs = cost.summarise(elapsed)
    metrics = score_run(cfg, truth, estimates)
    series = error_series(estimates, truth) if keep_series else None
    return ReplayResult(scenario, cfg.run.estimator, metrics, costs, cost.per_simulated_ms(costs, simulated),
                        cpu * 1e3 / simulated, series)


def error_series(estimates: list, truth) -> Series:
    """Roll and pitch errors, sigmas and NEES, averaged over bins of 1 / SERIES_RATE."""
    from scipy.spatial.transform import Rotation

    from estimators.scoring import estimate_arrays, nees_2d, roll_pitch_yaw, truth_at, wrap

    arrays = estimate_arrays(estimates)
    true = roll_pitch_yaw(truth_at(arrays.t, truth.t, Rotation.from_quat(truth.quaternion).as_matrix()))
    error = np.column_stack([wrap(arrays.roll - true[:, 0]), wrap(arrays.pitch - true[:, 1])])
    bins = np.floor((arrays.t - arrays.t[0]) * SERIES_RATE).astype(int)
    counts = np.bincount(bins)
    keep = counts > 0

    def binned(values: np.ndarray) -> np.ndarray:
        return np.bincount(bins, weights=values, minlength=len(counts))[keep] / counts[keep]

    t = binned(arrays.t)
    sigma = nees = None
    if arrays.tilt_cov is not None:
        sigma = np.column_stack([np.sqrt(binned(arrays.tilt_cov[:, 0, 0])), np.sqrt(binned(arrays.tilt_cov[:, 1, 1]))])
        nees = binned(nees_2d(error, arrays.tilt_cov))
    return Series(t, np.column_stack([binned(error[:, 0]), binned(error[:, 1])]), sigma, nees)


# --- the benchmark -----------------------------------------------------------------------------

@dataclass(frozen=True)
class BenchSet:
    """What to run. The grid: every terrain x contact x IMU grade x seed, fault-free, IMU only.
    Beside it, on the default grade (`side_grade`): the quad accelerometer array on
    `array_terrains` x contacts, fault-free; and each fault on `fault_terrains` x contacts with the
    `fault_array` layout, with the same walks without the fault as its reference."""
    terrains: tuple[str, ...] = TERRAINS
    contacts: tuple[str, ...] = CONTACTS
    grades: tuple[str, ...] = GRADES
    seeds: tuple[int, ...] = tuple(range(10))
    duration: float = 30.0
    estimators: tuple[str, ...] = ESTIMATOR_ORDER
    array_terrains: tuple[str, ...] = ("flat", "rough")
    faults: tuple[str, ...] = ("gyro_stuck", "gyro_bias_jump")
    fault_terrains: tuple[str, ...] = ("flat",)
    fault_seeds: tuple[int, ...] = tuple(range(10))
    fault_estimators: tuple[str, ...] = ("ekf", "complementary", "madgwick", "mahony", "vqf")
    fault_array: str = "quad"
    series_seed: int | None = 0          # keep the time series of this seed's runs

    @property
    def side_grade(self) -> str:
        return "default" if "default" in self.grades else self.grades[0]

    def scenarios(self) -> dict[Scenario, tuple[str, ...]]:
        """Every walk, once, with the estimators replayed on it (in the order of the tables)."""
        walks: dict[Scenario, tuple[str, ...]] = {}

        def add(scenario: Scenario, estimators: Sequence[str]) -> None:
            walks[scenario] = tuple(dict.fromkeys([*walks.get(scenario, ()), *estimators]))

        for terrain in self.terrains:
            for contact in self.contacts:
                for grade in self.grades:
                    for seed in self.seeds:
                        add(Scenario(terrain, seed, self.duration, contact=contact, grade=grade), self.estimators)
        for terrain in self.array_terrains:
            for contact in self.contacts:
                for seed in self.seeds:
                    add(Scenario(terrain, seed, self.duration, contact=contact, grade=self.side_grade,
                                 array="quad"), self.estimators)
        for fault in self.faults:
            for terrain in self.fault_terrains:
                for contact in self.contacts:
                    for seed in self.fault_seeds:
                        faulty = Scenario(terrain, seed, self.duration, fault, contact, self.side_grade,
                                          self.fault_array)
                        add(faulty.reference, self.fault_estimators)
                        add(faulty, self.fault_estimators)
        return walks

    def keeps_series(self, scenario: Scenario) -> bool:
        """The series seed's walks, and every walk of the NEES plot (compliant, side grade, IMU only)."""
        return scenario.seed == self.series_seed or (
            scenario.fault == "none" and scenario.array == "imu_only" and scenario.contact == "compliant"
            and scenario.grade == self.side_grade)

    def jobs(self, base: Base, cache_dir: Path) -> list[Job]:
        return [Job(scenario, scenario_config(scenario, base).to_dict(), estimators, str(cache_dir),
                    self.keeps_series(scenario)) for scenario, estimators in self.scenarios().items()]

    @property
    def is_full(self) -> bool:
        return self == BenchSet()


@dataclass
class BenchResult:
    bench_set: BenchSet
    replays: list[ReplayResult]
    wall_s: float
    recorded: int            # datasets simulated (the others came from the cache)
    workers: int
    failed: list[str] = field(default_factory=list)      # walks that could not be recorded, why


def run_bench(bench_set: BenchSet, base: Base = Base(), cache_dir: Path = CACHE,
              workers: int = 2, progress: Callable[[JobResult], None] | None = None) -> BenchResult:
    """Every job of the set on `workers` processes (1: in this process); results in job order."""
    jobs = bench_set.jobs(base, cache_dir)
    started = time.perf_counter()
    results = _run_jobs(jobs, workers, progress)
    replays = [replay for result in results for replay in result.replays]
    return BenchResult(bench_set, replays, time.perf_counter() - started, sum(r.recorded for r in results), workers,
                       [note for result in results for note in result.notes])


def cached_walks(jobs: Sequence[Job]) -> int:
    """How many of the jobs' datasets are in their cache already (or failed before)."""
    count = 0
    for job in jobs:
        path = Path(job.cache_dir) / f"{dataset_key(config_module.from_dict(job.config))}.mcap"
        count += path.exists() or path.with_suffix(".failed").exists()
    return count


def _run_jobs(jobs: Sequence[Job], workers: int, progress: Callable[[JobResult], None] | None) -> list[JobResult]:
    if workers <= 1:
        results = []
        for job in jobs:
            results.append(evaluate(job))
            if progress:
                progress(results[-1])
        return results
    for name in THREAD_VARIABLES:       # one thread per worker: the workers are the parallelism
        os.environ.setdefault(name, "1")
    results: list[JobResult | None] = [None] * len(jobs)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(evaluate, job): index for index, job in enumerate(jobs)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            if progress:
                progress(results[futures[future]])
    return results


# --- summary and targets -------------------------------------------------------------------------

POSE_KEYS = ("position_drift_pct", "position_rmse_m", "velocity_rmse_mps", "yaw_error_final_deg", "anees_pose")
POSE_DOF = 9            # anees_pose: position, velocity and attitude, 3 each


def pooled_rms(values: Iterable[float | None]) -> float | None:
    """RMS over runs of per-run RMS values (runs of equal length): the RMS over all their samples."""
    values = [v for v in values if v is not None]
    return float(np.sqrt(np.mean(np.square(values)))) if values else None


def mean(values: Iterable[float | None]) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


@dataclass(frozen=True)
class Row:
    """One estimator on one terrain, contact, grade, array layout and fault, over the seeds."""
    terrain: str
    contact: str
    grade: str
    array: str
    fault: str
    estimator: str
    runs: int
    duration: float                         # s, of each run
    roll_rmse_deg: float
    pitch_rmse_deg: float
    tilt_rmse_deg: float                    # sqrt((roll^2 + pitch^2) / 2), pooled
    tilt_error_max_deg: float
    anees_tilt: float | None
    anees_bounds: tuple[float, float] | None
    slope_error_deg: float | None           # the largest over the runs
    height_est_rmse_m: float | None
    cost_us_per_ms: float                   # median over runs
    position_drift_pct: float | None = None     # mean over the runs
    position_rmse_m: float | None = None        # pooled
    velocity_rmse_mps: float | None = None      # pooled
    yaw_error_final_deg: float | None = None    # RMS over the runs
    anees_pose: float | None = None
    anees_pose_bounds: tuple[float, float] | None = None

    @property
    def key(self) -> tuple[str, str, str, str, str]:
        """The walks it is over: terrain, contact, grade, array, fault."""
        return self.terrain, self.contact, self.grade, self.array, self.fault

    @property
    def yaw_deg_per_min(self) -> float | None:
        return None if self.yaw_error_final_deg is None else self.yaw_error_final_deg * 60.0 / self.duration


def summary_rows(replays: Sequence[ReplayResult]) -> list[Row]:
    groups: dict[tuple, list[ReplayResult]] = {}
    for replay in replays:
        s = replay.scenario
        groups.setdefault((s.terrain, s.contact, s.grade, s.array, s.fault, replay.estimator), []).append(replay)
    return [summary_row(key, group) for key, group in groups.items()]


def summary_row(key: tuple, group: Sequence[ReplayResult]) -> Row:
    from estimators.scoring import anees_bounds

    metrics = [r.metrics for r in group]
    roll, pitch = pooled_rms(m["roll_rmse_deg"] for m in metrics), pooled_rms(m["pitch_rmse_deg"] for m in metrics)
    anees = [m["anees_tilt"] for m in metrics if m.get("anees_tilt") is not None]
    anees_pose = [m["anees_pose"] for m in metrics if m.get("anees_pose") is not None]
    slopes = [m["slope_error_deg"] for m in metrics if m.get("slope_error_deg") is not None]
    return Row(*key, len(group), group[0].scenario.duration, roll, pitch, float(np.hypot(roll, pitch) / np.sqrt(2)),
               max(m["tilt_error_max_deg"] for m in metrics),
               mean(anees), anees_bounds(len(anees)) if anees else None,
               max(slopes) if slopes else None, pooled_rms(m.get("height_est_rmse_m") for m in metrics),
               float(np.median([r.cost_per_ms for r in group])),
               mean(m.get("position_drift_pct") for m in metrics), pooled_rms(m.get("position_rmse_m") for m in metrics),
               pooled_rms(m.get("velocity_rmse_mps") for m in metrics),
               pooled_rms(m.get("yaw_error_final_deg") for m in metrics),
               mean(anees_pose), anees_bounds(len(anees_pose), POSE_DOF) if anees_pose else None)


@dataclass(frozen=True)
class Check:
    group: str              # "rows", "faults" or "cost": the table it belongs to
    where: str              # the rows it is over, e.g. "flat · dart · default (10 runs)"
    target: str
    passed: bool | None     # None: not measured (the estimator does not give the quantity)
    detail: str

    @property
    def what(self) -> str:
        return f"{self.target}, {self.where}"


RMSE_TARGET_DEG = 0.15
CONSUMER_RMSE_TARGET_DEG = 0.4
DRIFT_TARGET_PCT = 1.0          # flat and slope, compliant contact
ROUGH_DRIFT_TARGET_PCT = 2.0    # rough ground, and DART contact
YAW_TARGET_DEG_PER_MIN = 1.0
FAULT_RATIO_TARGET = 2.0
COST_TARGET_US_PER_MS = 25.0


def where(key: tuple, runs: int) -> str:
    terrain, contact, grade, array, fault = key
    parts = [terrain, contact, grade] + ([] if array == "imu_only" else [f"{array} array"])
    return " · ".join(parts + ([] if fault == "none" else [fault])) + f" ({runs_text(runs)})"


def runs_text(runs: int) -> str:
    return f"{runs} run" + ("" if runs == 1 else "s")


def rmse_target(grade: str) -> float:
    return CONSUMER_RMSE_TARGET_DEG if grade == "consumer" else RMSE_TARGET_DEG


def drift_target(terrain: str, contact: str) -> float | None:
    """The issue's drift target for a row, None where it sets none (step and course, compliant)."""
    if contact == "dart" or terrain == "rough":
        return ROUGH_DRIFT_TARGET_PCT
    return DRIFT_TARGET_PCT if terrain in ("flat", "slope") else None


def target_checks(rows: Sequence[Row]) -> list[Check]:
    """Issue 18's done-when list for the `ekf`, on what `rows` hold: per fault-free IMU-only row,
    RMSE, the best baseline (not on the consumer grade), drift and yaw; per fault, RMSE against the
    fault-free walks and ANEES; the cost."""
    table = {(r.key, r.estimator): r for r in rows}
    checks: list[Check] = []
    grid = [r for r in rows if r.estimator == "ekf" and r.fault == "none" and r.array == "imu_only"]
    for ekf in grid:
        checks += row_checks(ekf, [table[(ekf.key, name)] for name in BASELINES if (ekf.key, name) in table])
    for faulty in (r for r in rows if r.estimator == "ekf" and r.fault != "none"):
        reference = table.get(((*faulty.key[:4], "none"), "ekf"))
        if reference is not None:
            checks += fault_checks(faulty, reference)
    if grid:
        median = float(np.median([r.cost_us_per_ms for r in grid]))
        checks.append(Check("cost", f"every fault-free row ({runs_text(sum(r.runs for r in grid))})",
                            f"ekf cost <= {COST_TARGET_US_PER_MS:g} µs per simulated ms",
                            median <= COST_TARGET_US_PER_MS,
                            f"{median:.1f} µs (median of the rows' medians; largest row "
                            f"{max(r.cost_us_per_ms for r in grid):.1f})"))
    return checks


def row_checks(ekf: Row, baselines: Sequence[Row]) -> list[Check]:
    at = where(ekf.key, ekf.runs)
    limit = rmse_target(ekf.grade)
    checks = [Check("rows", at, "roll/pitch RMSE", max(ekf.roll_rmse_deg, ekf.pitch_rmse_deg) <= limit,
                    f"{ekf.roll_rmse_deg:.3f} / {ekf.pitch_rmse_deg:.3f} ≤ {limit:g}")]
    if baselines and ekf.grade != "consumer":
        roll = min(baselines, key=lambda r: r.roll_rmse_deg)
        pitch = min(baselines, key=lambda r: r.pitch_rmse_deg)
        passed = ekf.roll_rmse_deg < roll.roll_rmse_deg and ekf.pitch_rmse_deg < pitch.pitch_rmse_deg
        checks.append(Check("rows", at, "below the best baseline", passed,
                            f"{roll.estimator} {roll.roll_rmse_deg:.3f} / {pitch.estimator} {pitch.pitch_rmse_deg:.3f}"))
    limit = drift_target(ekf.terrain, ekf.contact)
    if limit is not None:
        drift = ekf.position_drift_pct
        checks.append(Check("rows", at, "position drift", None if drift is None else drift <= limit,
                            "–" if drift is None else f"{drift:.2f} % ≤ {limit:g}"))
    rate = ekf.yaw_deg_per_min
    checks.append(Check("rows", at, "yaw per minute", None if rate is None else rate <= YAW_TARGET_DEG_PER_MIN,
                        "–" if rate is None else f"{rate:.2f}° ≤ {YAW_TARGET_DEG_PER_MIN:g}"))
    return checks


def fault_checks(faulty: Row, reference: Row) -> list[Check]:
    at = where(faulty.key, faulty.runs)
    ratio = max(faulty.roll_rmse_deg / reference.roll_rmse_deg, faulty.pitch_rmse_deg / reference.pitch_rmse_deg)
    checks = [Check("faults", at, f"RMSE ≤ {FAULT_RATIO_TARGET:g}× fault-free", ratio <= FAULT_RATIO_TARGET,
                    f"{faulty.roll_rmse_deg:.3f} / {faulty.pitch_rmse_deg:.3f} against {reference.roll_rmse_deg:.3f} / "
                    f"{reference.pitch_rmse_deg:.3f}: ×{ratio:.2f}")]
    if faulty.anees_tilt is not None:
        low, high = faulty.anees_bounds
        checks.append(Check("faults", at, "ANEES inside the 95 % bounds", low <= faulty.anees_tilt <= high,
                            f"{faulty.anees_tilt:.{2 if faulty.anees_tilt < 100 else 0}f} in [{low:.2f}, {high:.2f}]"))
    return checks
