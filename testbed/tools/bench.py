"""Estimator-accuracy benchmark (issue 8): record each scenario once, replay every estimator over the
same recorded sensor data, score, check the estimators issue's targets, report.

A scenario is a terrain, a seed, a duration and an optional sensor fault, walked with the tripod
gait, no controller and no estimator (the estimators only replay). Its dataset is an MCAP file in
the cache folder named by a hash of the resolved config (without the `[estimators]` tuning, which
replays do not need) and of the source of the packages that produce the data, so that a changed
simulator, sensor model or config records again and a retuned estimator does not. Files are
written under a temporary name and renamed: a cache is never left with half a file.

`testbed bench` (this module's `add_subcommands`) and `tests/benchmarks` run the same code;
`testbed.tools.bench_report` writes the tables and plots.
"""

from __future__ import annotations

import argparse
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
from testbed.model.errors import UserError

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(platformdirs.user_cache_dir("hexapod-testbed")) / "bench"    # ~/.cache/hexapod-testbed/bench on Linux
TERRAINS = ("flat", "slope", "step", "rough")
BASELINES = ("madgwick", "mahony", "vqf")          # the EKF must beat each of these on every terrain
FAULTS = ("none", "accel_spikes", "encoder_dropout", "gyro_bias_step")
GYRO_BIAS_STEP = 0.00873                            # rad/s, 0.5 deg/s on every axis
SERIES_RATE = 100.0                                 # Hz, time series kept for the plots
# Packages whose source shapes a recording; their digest is part of a dataset's cache key.
DATA_SOURCES = ("testbed", "sensors", "datasets")
NOT_DATA_SOURCES = ("bench.py", "bench_report.py", "cli.py", "sweep.py", "sweep_cli.py", "profile.py",
                    "profile_cli.py", "commands.py", "info.py", "rerun_export.py", "replay.py")
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


@dataclass(frozen=True)
class Scenario:
    terrain: str
    seed: int
    duration: float         # s
    fault: str = "none"     # one of FAULTS

    @property
    def label(self) -> str:
        return f"{self.terrain}/seed {self.seed}" + ("" if self.fault == "none" else f"/{self.fault}")


def fault_specs(fault: str, duration: float) -> list[str]:
    """The sensors' fault specs (docs/sensors.md) of a fault kind, placed within a run of `duration`:
    full-scale accelerometer spikes at 20, 40, 60 and 80 % of it, a 1 s encoder dropout or a
    0.5 deg/s gyro bias step on every axis from 40 %."""
    at = round(0.4 * duration, 3)
    if fault == "none":
        return []
    if fault == "accel_spikes":
        return [f"imu.accel.spike@{round(f * duration, 3)}s" for f in (0.2, 0.4, 0.6, 0.8)]
    if fault == "encoder_dropout":
        return [f"encoder.dropout@{at}s+1s"]
    if fault == "gyro_bias_step":
        return [f"imu.gyro.bias_step@{at}s:{GYRO_BIAS_STEP}"]
    raise UserError(f"unknown fault '{fault}' (choose from {', '.join(FAULTS)})")


@dataclass(frozen=True)
class Base:
    """What a user puts under every scenario: a config file's overrides, a sensor preset."""
    config: dict[str, Any] | None = None
    preset: str | None = None


def scenario_config(scenario: Scenario, base: Base = Base()) -> Config:
    """Defaults, then the user's config file, then the sensor preset, then the scenario."""
    from testbed.runtime.presets import preset_overrides

    cfg = config_module.load(None, preset_overrides(base.preset) if base.preset else None, base=base.config)
    faults = [*cfg.sensors.faults, *fault_specs(scenario.fault, scenario.duration)]
    return cfg.replace(run={"terrain": scenario.terrain, "seed": scenario.seed, "duration": scenario.duration,
                            "gait": "tripod", "estimator": "none", "controller": "none"},
                       sensors={"faults": faults})


@cache
def source_digest() -> str:
    """sha256 of the source files that produce a recording (not the estimators: they only replay)."""
    digest = hashlib.sha256()
    for package in DATA_SOURCES:
        for path in sorted((ROOT / package).glob("*.py")):
            if path.name not in NOT_DATA_SOURCES:
                digest.update(path.name.encode())
                digest.update(path.read_bytes())
        for path in sorted((ROOT / package).glob("*.toml")):
            digest.update(path.read_bytes())
    return digest.hexdigest()


def dataset_key(cfg: Config) -> str:
    """Cache key of a scenario's dataset: its config without the estimator tuning, and the source."""
    data = cfg.to_dict()
    data.pop("estimators")
    data["run"]["estimator"] = "none"
    text = json.dumps(data, sort_keys=True) + source_digest()
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def dataset(cfg: Config, cache_dir: Path = CACHE) -> tuple[Path, bool]:
    """The scenario's recording, simulated now unless cached: (path, recorded now)."""
    path = Path(cache_dir) / f"{dataset_key(cfg)}.mcap"
    if path.exists():
        return path, False
    from datasets.recorder import McapRecorder
    from testbed.runtime.runner import run

    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.mcap")
    try:
        outcome = run(cfg, McapRecorder(temporary))
        if outcome.error or outcome.metrics.get("fell"):
            raise RuntimeError(f"{cfg.run.terrain} seed {cfg.run.seed}: the recording run failed "
                               f"({outcome.error or 'the robot fell'})")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
        temporary.with_name(temporary.name + ".partial").unlink(missing_ok=True)
    return path, True


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
    replays: list[ReplayResult]
    recorded: bool
    record_s: float
    replay_s: float = 0.0
    notes: list[str] = field(default_factory=list)


def evaluate(job: Job) -> JobResult:
    """Record (or reuse) the scenario's dataset and replay every estimator over it."""
    from datasets.reader import REPLAY_TOPICS, read_recording

    cfg = config_module.from_dict(job.config)
    started = time.perf_counter()
    path, recorded = dataset(cfg, Path(job.cache_dir))
    result = JobResult([], recorded, time.perf_counter() - started)
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
    """What to run: every terrain x seed fault-free, and the faults on some terrains and seeds."""
    terrains: tuple[str, ...] = TERRAINS
    seeds: tuple[int, ...] = tuple(range(10))
    duration: float = 20.0
    estimators: tuple[str, ...] = ESTIMATORS.names()
    faults: tuple[str, ...] = FAULTS[1:]
    fault_terrains: tuple[str, ...] = ("flat",)
    fault_seeds: tuple[int, ...] = tuple(range(10))
    fault_estimators: tuple[str, ...] = ("ekf", "complementary", "madgwick", "mahony", "vqf")
    series_seed: int | None = 0          # keep the time series of this seed's runs (and all NEES)

    def jobs(self, base: Base, cache_dir: Path) -> list[Job]:
        jobs = []
        for terrain in self.terrains:
            for seed in self.seeds:
                scenario = Scenario(terrain, seed, self.duration)
                jobs.append(Job(scenario, scenario_config(scenario, base).to_dict(), self.estimators, str(cache_dir),
                                True))
        for fault in self.faults:
            for terrain in self.fault_terrains:
                for seed in self.fault_seeds:
                    scenario = Scenario(terrain, seed, self.duration, fault)
                    jobs.append(Job(scenario, scenario_config(scenario, base).to_dict(), self.fault_estimators,
                                    str(cache_dir), seed == self.series_seed))
        return jobs


@dataclass
class BenchResult:
    bench_set: BenchSet
    replays: list[ReplayResult]
    wall_s: float
    recorded: int            # datasets simulated (the others came from the cache)
    workers: int


def run_bench(bench_set: BenchSet, base: Base = Base(), cache_dir: Path = CACHE,
              workers: int = 2, progress: Callable[[JobResult], None] | None = None) -> BenchResult:
    """Every job of the set on `workers` processes (1: in this process); results in job order."""
    jobs = bench_set.jobs(base, cache_dir)
    started = time.perf_counter()
    results = _run_jobs(jobs, workers, progress)
    replays = [replay for result in results for replay in result.replays]
    return BenchResult(bench_set, replays, time.perf_counter() - started, sum(r.recorded for r in results), workers)


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

def pooled_rms(values: Iterable[float | None]) -> float | None:
    """RMS over runs of per-run RMS values (runs of equal length): the RMS over all their samples."""
    values = [v for v in values if v is not None]
    return float(np.sqrt(np.mean(np.square(values)))) if values else None


@dataclass(frozen=True)
class Row:
    """One estimator on one terrain (one fault), over the seeds."""
    terrain: str
    fault: str
    estimator: str
    runs: int
    roll_rmse_deg: float
    pitch_rmse_deg: float
    tilt_rmse_deg: float                    # sqrt((roll^2 + pitch^2) / 2), pooled
    tilt_error_max_deg: float
    anees_tilt: float | None
    anees_bounds: tuple[float, float] | None
    slope_error_deg: float | None           # the largest over the runs
    height_est_rmse_m: float | None
    cost_us_per_ms: float                   # median over runs


def summary_rows(replays: Sequence[ReplayResult]) -> list[Row]:
    from estimators.scoring import anees_bounds

    groups: dict[tuple[str, str, str], list[ReplayResult]] = {}
    for replay in replays:
        groups.setdefault((replay.scenario.terrain, replay.scenario.fault, replay.estimator), []).append(replay)
    rows = []
    for (terrain, fault, estimator), group in groups.items():
        metrics = [r.metrics for r in group]
        roll, pitch = pooled_rms(m["roll_rmse_deg"] for m in metrics), pooled_rms(m["pitch_rmse_deg"] for m in metrics)
        anees = [m["anees_tilt"] for m in metrics if m["anees_tilt"] is not None]
        slopes = [m["slope_error_deg"] for m in metrics if m["slope_error_deg"] is not None]
        rows.append(Row(terrain, fault, estimator, len(group), roll, pitch, float(np.hypot(roll, pitch) / np.sqrt(2)),
                        max(m["tilt_error_max_deg"] for m in metrics),
                        float(np.mean(anees)) if anees else None, anees_bounds(len(anees)) if anees else None,
                        max(slopes) if slopes else None, pooled_rms(m["height_est_rmse_m"] for m in metrics),
                        float(np.median([r.cost_per_ms for r in group]))))
    return rows


@dataclass(frozen=True)
class Check:
    what: str
    passed: bool
    detail: str


RMSE_TARGET_DEG = 0.3
SLOPE_TARGET_DEG = 1.0
HEIGHT_TARGET_M = 0.005
FAULT_RATIO_TARGET = 2.0
DIVERGED_DEG = 10.0


def target_checks(rows: Sequence[Row], anees_per_terrain: bool = True) -> list[Check]:
    """The estimators issue's done-when list, for the `ekf`, on what `rows` hold."""
    table = {(r.terrain, r.fault, r.estimator): r for r in rows}
    checks: list[Check] = []
    clean = [r for r in rows if r.fault == "none" and r.estimator == "ekf"]
    for ekf in clean:
        where = f"{ekf.terrain} ({ekf.runs} runs)"
        checks.append(Check(f"ekf roll and pitch RMSE <= {RMSE_TARGET_DEG} deg, {where}",
                            max(ekf.roll_rmse_deg, ekf.pitch_rmse_deg) <= RMSE_TARGET_DEG,
                            f"{ekf.roll_rmse_deg:.3f} / {ekf.pitch_rmse_deg:.3f} deg"))
        for name in BASELINES:
            other = table.get((ekf.terrain, "none", name))
            if other is not None:
                checks.append(Check(f"ekf below {name}, {where}", ekf.roll_rmse_deg < other.roll_rmse_deg
                                    and ekf.pitch_rmse_deg < other.pitch_rmse_deg,
                                    f"{ekf.roll_rmse_deg:.3f} / {ekf.pitch_rmse_deg:.3f} against "
                                    f"{other.roll_rmse_deg:.3f} / {other.pitch_rmse_deg:.3f} deg"))
        if anees_per_terrain and ekf.anees_tilt is not None:
            low, high = ekf.anees_bounds
            checks.append(Check(f"ekf ANEES inside the 95 % chi-square bounds, {where}", low <= ekf.anees_tilt <= high,
                                f"{ekf.anees_tilt:.2f} in [{low:.2f}, {high:.2f}]"))
        if ekf.terrain == "slope" and ekf.slope_error_deg is not None:
            checks.append(Check(f"ekf terrain slope within {SLOPE_TARGET_DEG} deg after 2 s, {where}",
                                ekf.slope_error_deg <= SLOPE_TARGET_DEG, f"largest error {ekf.slope_error_deg:.2f} deg"))
        if ekf.height_est_rmse_m is not None:
            checks.append(Check(f"ekf body height RMS <= {HEIGHT_TARGET_M * 1e3:.0f} mm, {where}",
                                ekf.height_est_rmse_m <= HEIGHT_TARGET_M, f"{ekf.height_est_rmse_m * 1e3:.2f} mm"))
    if not anees_per_terrain and clean:
        checks.append(pooled_anees_check(clean))
    for faulty in (r for r in rows if r.fault != "none" and r.estimator == "ekf"):
        reference = table.get((faulty.terrain, "none", "ekf"))
        if reference is None:
            continue
        ratio = faulty.tilt_rmse_deg / reference.tilt_rmse_deg
        checks.append(Check(f"ekf with {faulty.fault}: RMSE under {FAULT_RATIO_TARGET:.0f}x fault-free, no divergence, "
                            f"{faulty.terrain} ({faulty.runs} runs)",
                            ratio < FAULT_RATIO_TARGET and faulty.tilt_error_max_deg < DIVERGED_DEG,
                            f"x{ratio:.2f}, largest tilt error {faulty.tilt_error_max_deg:.2f} deg"))
    return checks


def pooled_anees_check(rows: Sequence[Row]) -> Check:
    """ANEES over every fault-free run of every terrain (a small set has too few runs per terrain)."""
    from estimators.scoring import anees_bounds

    runs = sum(r.runs for r in rows)
    anees = sum(r.anees_tilt * r.runs for r in rows) / runs
    low, high = anees_bounds(runs)
    return Check(f"ekf ANEES inside the 95 % chi-square bounds, all terrains ({runs} runs)", low <= anees <= high,
                 f"{anees:.2f} in [{low:.2f}, {high:.2f}]")


# --- command line --------------------------------------------------------------------------------
