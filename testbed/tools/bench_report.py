"""Tables and plots of the estimator benchmark (testbed.tools.bench): Markdown, CSV, JSON and PNG.

`write(result, checks, folder)` is what `testbed bench --out DIR` writes; `write_docs` refreshes
docs/results/estimators.{md,csv,json} and docs/img/estimators_*.png, then docs/results.md: the
estimators' fragment, then every other fragment docs/results/*.md that other benchmarks write,
verbatim, sorted by name (`python -m testbed.tools.bench_report` assembles it again). Every file is
written to a temporary name and renamed.
"""

from __future__ import annotations

import csv
import io
import json
import os
import platform
from collections.abc import Sequence
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from testbed.runtime.outputs import write_atomically
from testbed.tools.bench import (BASELINES, FAULT_RATIO_TARGET, POSE_KEYS, BenchResult,
                                 BenchSet, Check, ReplayResult, Row, rmse_target, runs_text, summary_rows, where)

DOCS = Path(__file__).resolve().parents[2] / "docs"
METRIC_COLUMNS = ("roll_rmse_deg", "pitch_rmse_deg", "tilt_error_max_deg", "slope_error_deg", "height_est_rmse_m",
                  "anees_tilt") + POSE_KEYS
COLORS = {"ekf": "C3", "ukf": "C1", "complementary": "C7", "madgwick": "C2", "mahony": "C4", "vqf": "C0"}
SCORING_SKIP = 1.0     # s, the first second is not scored (estimators.scoring.score's default skip)
RANGE_PERCENTILE = 99.0    # the error plots' y range holds this percentile of each estimator's scored |error|
RANGE_RMS_FACTOR = 3.0     # ... of the estimators whose RMS error is at most this many times the lowest


# --- files ---------------------------------------------------------------------------------------

def run_rows(replays: Sequence[ReplayResult]) -> list[dict]:
    """One row per replay: the scenario, the estimator, its metrics and its cost."""
    rows = []
    for r in replays:
        s = r.scenario
        row = {"terrain": s.terrain, "contact": s.contact, "grade": s.grade, "array": s.array, "seed": s.seed,
               "duration_s": s.duration, "fault": s.fault, "estimator": r.estimator}
        row.update({key: r.metrics.get(key) for key in METRIC_COLUMNS})
        row["cost_us_per_ms"] = r.cost_per_ms
        row["cpu_us_per_ms"] = r.cpu_per_ms
        for kind, cost in sorted(r.cost.items()):
            row[f"{kind}_median_us"] = cost["median_us"]
        rows.append(row)
    return rows


def csv_text(rows: list[dict]) -> str:
    columns = list(dict.fromkeys(key for row in rows for key in row))
    out = io.StringIO()
    writer = csv.DictWriter(out, columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


def json_text(result: BenchResult, checks: Sequence[Check]) -> str:
    document = {"bench_set": asdict(result.bench_set), "wall_s": result.wall_s, "recorded": result.recorded,
                "workers": result.workers, "failed": result.failed,
                "summary": [asdict(row) for row in summary_rows(result.replays)],
                "checks": [asdict(check) for check in checks], "runs": run_rows(result.replays)}
    return json.dumps(_finite(document), indent=1, sort_keys=True) + "\n"


def _finite(value):
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    if isinstance(value, np.generic):
        return _finite(value.item())
    return value


# --- Markdown ------------------------------------------------------------------------------------

def number_cell(value: float | None, digits: int = 3, scale: float = 1.0) -> str:
    """A table cell: the value times `scale` to `digits` decimals, "–" when there is none."""
    return "–" if value is None else f"{value * scale:.{digits}f}"


def load_average() -> float:
    """The machine's 1-minute load average (NaN where the system gives none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def _anees(value: float | None, bounds: tuple[float, float] | None) -> str:
    return "–" if value is None else f"{value:.{2 if value < 100 else 0}f} ({bounds[0]:.2f}–{bounds[1]:.2f})"


def _table(header: Sequence[str], lines: Sequence[Sequence[str]]) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                     + ["| " + " | ".join(line) + " |" for line in lines])


# Columns of the full-state metrics: (key, heading, cell), shown when any run gives the key.
POSE_COLUMNS = (
    ("position_drift_pct", "drift (%)", lambda r: number_cell(r.position_drift_pct, 2)),
    ("position_rmse_m", "position RMSE (cm)", lambda r: number_cell(r.position_rmse_m, 2, 100.0)),
    ("velocity_rmse_mps", "velocity RMSE (cm/s)", lambda r: number_cell(r.velocity_rmse_mps, 2, 100.0)),
    ("yaw_error_final_deg", "final yaw error (°)", lambda r: number_cell(r.yaw_error_final_deg, 2)),
    ("anees_pose", "ANEES pose (bounds)", lambda r: _anees(r.anees_pose, r.anees_pose_bounds)),
)


def pose_columns(replays: Sequence[ReplayResult]) -> list[tuple]:
    """The full-state columns some run's metrics carry a value of."""
    given = {key for r in replays for key in POSE_KEYS if r.metrics.get(key) is not None}
    return [column for column in POSE_COLUMNS if column[0] in given]


def best_of(rows: Sequence[Row], attribute: str) -> Row:
    return min(rows, key=lambda r: getattr(r, attribute))


def terrain_table(rows: Sequence[Row], terrain: str, columns: Sequence[tuple]) -> str:
    """Every fault-free IMU-only row of a terrain: contact x grade x estimator; the lowest roll and
    pitch RMSE of each contact and grade in bold."""
    mine = [r for r in rows if r.terrain == terrain and r.fault == "none" and r.array == "imu_only"]
    groups: dict[tuple[str, str], list[Row]] = {}
    for row in mine:
        groups.setdefault((row.contact, row.grade), []).append(row)
    lines = []
    for group in groups.values():
        best_roll, best_pitch = best_of(group, "roll_rmse_deg"), best_of(group, "pitch_rmse_deg")
        for row in group:
            roll, pitch = f"{row.roll_rmse_deg:.3f}", f"{row.pitch_rmse_deg:.3f}"
            lines.append([row.contact, row.grade, f"**{row.estimator}**" if row.estimator == "ekf" else row.estimator,
                          f"**{roll}**" if row is best_roll else roll, f"**{pitch}**" if row is best_pitch else pitch,
                          f"{row.tilt_error_max_deg:.2f}", _anees(row.anees_tilt, row.anees_bounds),
                          number_cell(row.height_est_rmse_m, 2, 1e3), *(cell(row) for _, _, cell in columns),
                          f"{row.cost_us_per_ms:.1f}"])
    header = ["contact", "IMU", "estimator", "roll RMSE (°)", "pitch RMSE (°)", "max tilt error (°)",
              "ANEES (bounds)", "height RMS (mm)", *(heading for _, heading, _ in columns), "cost (µs / sim. ms)"]
    return _table(header, lines)


def array_table(rows: Sequence[Row], columns: Sequence[tuple]) -> str:
    """Fault-free walks with the quad accelerometer array against the same walks without it."""
    table = {(r.key, r.estimator): r for r in rows}
    lines = []
    for on in (r for r in rows if r.array != "imu_only" and r.fault == "none"):
        off = table.get(((on.terrain, on.contact, on.grade, "imu_only", "none"), on.estimator))
        if off is None:
            continue
        lines.append([on.terrain, on.contact, on.grade, on.estimator,
                      f"{off.roll_rmse_deg:.3f} / {off.pitch_rmse_deg:.3f}", f"{on.roll_rmse_deg:.3f} / {on.pitch_rmse_deg:.3f}",
                      _anees(off.anees_tilt, off.anees_bounds), _anees(on.anees_tilt, on.anees_bounds),
                      *(f"{cell(off)} / {cell(on)}" for key, _, cell in columns if key != "anees_pose"),
                      f"{off.cost_us_per_ms:.1f} / {on.cost_us_per_ms:.1f}"])
    if not lines:
        return ""
    header = ["terrain", "contact", "IMU", "estimator", "roll / pitch RMSE off (°)", "on (°)", "ANEES off", "ANEES on",
              *(f"{heading} off / on" for key, heading, _ in columns if key != "anees_pose"), "cost off / on (µs / sim. ms)"]
    return _table(header, lines)


def fault_table(rows: Sequence[Row]) -> str:
    table = {(r.key, r.estimator): r for r in rows}
    lines = []
    for row in (r for r in rows if r.fault != "none"):
        clean = table.get(((*row.key[:4], "none"), row.estimator))
        ratio = "–" if clean is None else \
            f"{max(row.roll_rmse_deg / clean.roll_rmse_deg, row.pitch_rmse_deg / clean.pitch_rmse_deg):.2f}"
        reference = "–" if clean is None else f"{clean.roll_rmse_deg:.3f} / {clean.pitch_rmse_deg:.3f}"
        lines.append([row.terrain, row.contact, row.grade, row.array, row.fault, row.estimator,
                      f"{row.roll_rmse_deg:.3f} / {row.pitch_rmse_deg:.3f}", reference, ratio,
                      f"{row.tilt_error_max_deg:.2f}", _anees(row.anees_tilt, row.anees_bounds)])
    if not lines:
        return ""
    return _table(["terrain", "contact", "IMU", "array", "fault", "estimator", "roll / pitch RMSE (°)",
                   "fault-free (°)", "ratio (worse axis)", "max tilt error (°)", "ANEES (bounds)"], lines)


def _met(check: Check | None) -> str:
    if check is None:
        return "n/a"
    return "–" if check.passed is None else "yes" if check.passed else "**no**"


def targets_table(checks: Sequence[Check], rows: Sequence[Row]) -> str:
    """One line per terrain x contact x grade: the EKF's RMSE against its limit, the best baseline
    and whether the EKF is below it, the best of all estimators, drift and yaw."""
    by_where: dict[str, dict[str, Check]] = {}
    for check in checks:
        if check.group == "rows":
            by_where.setdefault(check.where, {})[check.target] = check
    best = best_estimators(rows)
    lines = []
    for where, mine in by_where.items():
        rmse, baseline = mine["roll/pitch RMSE"], mine.get("below the best baseline")
        drift, yaw = mine.get("position drift"), mine["yaw per minute"]
        lines.append([where, rmse.detail, _met(rmse), "–" if baseline is None else baseline.detail, _met(baseline),
                      best.get(where, "–"), "–" if drift is None else drift.detail, _met(drift), yaw.detail, _met(yaw)])
    return _table(["walks", "ekf roll / pitch RMSE (°) ≤ limit", "met", "best baseline roll / pitch (°)",
                   "ekf below it", "best of all (roll / pitch)", "ekf drift", "met", "ekf yaw (° / min)", "met"], lines)


def best_estimators(rows: Sequence[Row]) -> dict[str, str]:
    """Per fault-free IMU-only walk set (labelled as the checks' `where`): the estimators with the
    lowest roll and pitch RMSE, one name if the same."""
    groups: dict[tuple, list[Row]] = {}
    for row in rows:
        if row.fault == "none" and row.array == "imu_only":
            groups.setdefault(row.key, []).append(row)
    best = {}
    for key, group in groups.items():
        roll, pitch = best_of(group, "roll_rmse_deg").estimator, best_of(group, "pitch_rmse_deg").estimator
        ekf = next((r for r in group if r.estimator == "ekf"), None)
        if ekf is not None:
            best[where(key, ekf.runs)] = roll if roll == pitch else f"{roll} / {pitch}"
    return best


def fault_targets_table(checks: Sequence[Check]) -> str:
    by_where: dict[str, dict[str, Check]] = {}
    for check in checks:
        if check.group == "faults":
            by_where.setdefault(check.where, {})[check.target] = check
    if not by_where:
        return ""
    ratio_target = f"RMSE ≤ {FAULT_RATIO_TARGET:g}× fault-free"
    lines = []
    for where, mine in by_where.items():
        ratio, anees = mine[ratio_target], mine.get("ANEES inside the 95 % bounds")
        lines.append([where, ratio.detail, _met(ratio), "–" if anees is None else anees.detail, _met(anees)])
    return _table(["ekf, walks", "roll / pitch RMSE (°) against fault-free", "≤ 2×", "ANEES in [95 % bounds]",
                   "inside"], lines)


def checks_table(checks: Sequence[Check]) -> str:
    """Every target, what was measured and whether it is met."""
    return _table(("target", "measured", "met"), [(c.what, c.detail, "yes" if c.passed else "**no**") for c in checks])


def checks_summary(checks: Sequence[Check]) -> str:
    measured = [c for c in checks if c.passed is not None]
    met = sum(c.passed for c in measured)
    unmeasured = len(checks) - len(measured)
    return (f"Targets met: **{met} of {len(measured)}** measured" +
            (f"; {unmeasured} not measured (–: the EKF's metrics do not carry the quantity yet)" if unmeasured else "")
            + ".")


def cost_table(replays: Sequence[ReplayResult]) -> str:
    """Median update cost per sample type over every replay, per estimator."""
    kinds = ("ImuSample", "EncoderSample", "FootSample")
    lines = []
    for name in dict.fromkeys(r.estimator for r in replays):
        mine = [r for r in replays if r.estimator == name]
        medians = [np.median([r.cost[k]["median_us"] for r in mine if k in r.cost] or [np.nan]) for k in kinds]
        lines.append([name, *(f"{m:.1f}" for m in medians), f"{np.median([r.cost_per_ms for r in mine]):.1f}",
                      f"{np.median([r.cpu_per_ms for r in mine]):.1f}"])
    return _table(["estimator", "IMU sample (µs)", "encoder sample (µs)", "foot sample (µs)",
                   "per simulated ms (µs)", "CPU per simulated ms (µs)"], lines)


def _listed(values: Sequence) -> str:
    return ", ".join(str(v) for v in values) if values else "none"


def _seeds(seeds: Sequence[int]) -> str:
    return f"{seeds[0]}–{seeds[-1]}" if len(seeds) > 1 and list(seeds) == list(range(seeds[0], seeds[-1] + 1)) \
        else _listed(seeds)


def coverage(bench_set: BenchSet) -> str:
    """What the set covers, and whether it is the full set of `make bench`."""
    s = bench_set
    text = (f"terrains {_listed(s.terrains)} × contact {_listed(s.contacts)} × IMU grade {_listed(s.grades)} × "
            f"seeds {_seeds(s.seeds)}, {s.duration:g} s walks")
    if s.array_terrains:
        text += f"; the quad accelerometer array on {_listed(s.array_terrains)} ({s.side_grade} grade)"
    if s.faults:
        text += (f"; faults {_listed(s.faults)} on {_listed(s.fault_terrains)} ({s.side_grade} grade, "
                 f"{s.fault_array} array), seeds {_seeds(s.fault_seeds)}")
    if s.is_full:
        return f"The full set: {text}."
    full = BenchSet()
    return (f"**Reduced set**: {text}. The full set (`make bench`) is {_listed(full.terrains)} × "
            f"{_listed(full.contacts)} × {_listed(full.grades)} × seeds {_seeds(full.seeds)}, {full.duration:g} s; "
            f"figures over fewer seeds have wider ANEES bounds and are no verdict on the issue's targets.")


def markdown(result: BenchResult, checks: Sequence[Check], image_folder: str) -> str:
    rows = summary_rows(result.replays)
    bench_set = result.bench_set
    columns = pose_columns(result.replays)
    terrains = list(dict.fromkeys(r.terrain for r in rows if r.fault == "none" and r.array == "imu_only"))
    load = load_average()
    parts = [
        coverage(bench_set),
        f"Tripod walks at the default 0.1 m/s, controller off (the bench's course: `testbed/tools/bench.py` COURSE, "
        f"a ramp up, a step up, stairs down, rough blocks, a ramp down); every estimator replays the same recorded "
        f"sensor data; the first second is not scored. IMU grades are the sensor presets (`consumer` MPU-6050, "
        f"`default` BMI088, `tactical` ADIS16470, with the EKF's matching noise beliefs). RMSE pooled over the seeds "
        f"(RMS of every sample); ANEES averaged over the runs with the 95 % chi-square bounds for that many runs "
        f"(2 dof for roll and pitch, 9 for the pose); drift: mean over the runs; final yaw error: RMS over the runs. "
        f"Cost: the median wall time of one update of each sample type times its rate (IMU 1 kHz, encoders 200 Hz, "
        f"feet 250 Hz), median over the runs; the CPU column is the replay's whole process time per simulated ms, "
        f"which a busy machine inflates. Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC on "
        f"{platform.machine()} with {os.cpu_count()} CPUs, load average {load:.1f}, {result.workers} worker "
        f"processes, in {result.wall_s / 60:.1f} min ({result.recorded} walks simulated, the rest from the dataset "
        f"cache).",
        "### Targets (issue 18)",
        f"The EKF on every fault-free IMU-only walk set: roll and pitch RMSE at most {rmse_target('default'):g}° "
        f"(default and tactical IMU) or {rmse_target('consumer'):g}° (consumer), and below the best of "
        f"{', '.join(BASELINES)} on each axis (default and tactical); position drift at most 1 % on flat and slope, "
        f"2 % on rough ground and DART contact (step and course, compliant: no target); yaw at most 1° per "
        f"simulated minute. \"Best of all\" names the estimators with the lowest roll and pitch RMSE on the row, "
        f"UKF included: where it is not the EKF, the EKF is not best on that row. –: not measured.",
        targets_table(checks, rows), checks_summary(checks)]
    faults = fault_targets_table(checks)
    if faults:
        parts += [f"Faults, EKF: roll and pitch RMSE at most {FAULT_RATIO_TARGET:g}× the same walks' without the "
                  f"fault, and ANEES inside its 95 % bounds.", faults]
    cost = [c for c in checks if c.group == "cost"]
    parts += [f"Cost: {c.target}: {c.detail}: {_met(c)}." for c in cost]
    parts.append("Not measured by this benchmark: the walk to a target within 3 cm on the estimator's own "
                 "position (a controlled walk, not a replay; `../shared/acceptance/estimation`).")
    if result.failed:
        parts += ["Walks that could not be recorded (no replays): " + "; ".join(result.failed) + "."]
    for terrain in terrains:
        parts += [f"### {terrain}", terrain_table(rows, terrain, columns),
                  f"![{terrain}: errors over time]({image_folder}/estimators_error_{terrain}.png)"]
    arrays = array_table(rows, columns)
    if arrays:
        parts += ["### Accelerometer array", "The same walks recorded with the quad array (`sensors.accel_array."
                  "layout = \"quad\"`, four accelerometers at the top plate's corners) and without it (IMU only); "
                  "estimators that do not read the array give the same figures on both.", arrays]
    faults = fault_table(rows)
    if faults:
        parts += ["### Sensor faults", f"From 40 % of each walk: `gyro_stuck` holds the gyro for 2 s, `gyro_bias_jump` "
                  f"adds 0.5 rad/s to its x axis for 2 s, `gyro_bias_step` 0.5°/s on every axis to the end, "
                  f"`accel_spikes` four full-scale samples, `encoder_dropout` 1 s without encoders "
                  f"(`testbed.tools.bench.fault_specs`). Fault-free reference: the same seeds and walks without the "
                  f"fault.", faults]
    parts += ["### Summary plots", f"![Tilt RMSE per estimator, terrain, contact and IMU grade]({image_folder}/"
              f"estimators_rmse.png)", f"![EKF NEES against the chi-square bounds]({image_folder}/estimators_nees.png)",
              "### Cost per update", cost_table(result.replays)]
    return "\n\n".join(parts) + "\n"


# --- plots ---------------------------------------------------------------------------------------

def new_figure(rows: int, columns: int, size: tuple[float, float]):
    """A figure of rows x columns axes (matplotlib imported here: only the plots need it)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(rows, columns, figsize=size, squeeze=False, constrained_layout=True)


def save_png(figure, path: Path, dpi: int = 110) -> None:
    import matplotlib.pyplot as plt
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    plt.close(figure)
    write_atomically(path, buffer.getvalue())


def plot_errors(replays: Sequence[ReplayResult], terrain: str, path: Path) -> None:
    figure = error_figure(replays, terrain)
    if figure is not None:
        save_png(figure, path)


def _plotted_walks(replays: Sequence[ReplayResult], terrain: str) -> list[ReplayResult]:
    """The fault-free IMU-only replays with series of a terrain, on the default grade if it ran
    (else the first grade), of the lowest seed."""
    walks = [r for r in replays if r.scenario.terrain == terrain and r.scenario.fault == "none"
             and r.scenario.array == "imu_only" and r.series]
    if not walks:
        return []
    grades = list(dict.fromkeys(r.scenario.grade for r in walks))
    grade = "default" if "default" in grades else grades[0]
    seed = min(r.scenario.seed for r in walks if r.scenario.grade == grade)
    return [r for r in walks if r.scenario.grade == grade and r.scenario.seed == seed]


def error_figure(replays: Sequence[ReplayResult], terrain: str):
    """Roll and pitch errors over time of one walk per contact (the lowest seed with series, the
    default grade): each estimator once, the EKF with its 3-sigma band, one legend beside the axes.
    The y range holds RANGE_PERCENTILE of the scored errors (after the first second) of the
    estimators near the best (`_error_range`), so the sub-degree differences show; the start-up,
    the wider bands and the far worse filters are cut off at it. None
    without series of that terrain."""
    walks = _plotted_walks(replays, terrain)
    if not walks:
        return None
    contacts = list(dict.fromkeys(r.scenario.contact for r in walks))
    figure, axes = new_figure(2, len(contacts), (6.0 * len(contacts) + 2.0, 5.5))
    handles = {}
    for column, contact in enumerate(contacts):
        mine = list({r.estimator: r for r in walks if r.scenario.contact == contact}.values())
        for row, angle in enumerate(("roll", "pitch")):
            axis = axes[row, column]
            for replay in mine:
                handles.update(_plot_error(axis, replay, row))
            axis.set_ylim(*_error_range(mine, row))
            axis.axvline(SCORING_SKIP, color="k", lw=0.5, ls=":")
            axis.set_ylabel(f"{angle} error (°)")
            axis.grid(alpha=0.3)
        axes[0, column].set_title(f"{terrain}, {contact}, {mine[0].scenario.grade} IMU, seed {mine[0].scenario.seed}",
                                  fontsize=10)
        axes[1, column].set_xlabel("time (s)")
    figure.suptitle(f"estimate − truth (dotted: the first second, not scored); y range: the estimators within "
                    f"{RANGE_RMS_FACTOR:g}× the lowest RMS error", fontsize=10)
    figure.legend(list(handles.values()), list(handles), loc="outside right center", fontsize=8)
    return figure


def _plot_error(axis, replay: ReplayResult, row: int) -> dict:
    series = replay.series
    handles = {}
    if replay.estimator == "ekf" and series.sigma is not None:
        band = 3 * np.degrees(series.sigma[:, row])
        handles["ekf ±3σ"] = axis.fill_between(series.t, -band, band, color=COLORS["ekf"], alpha=0.15, lw=0)
    wide = replay.estimator == "ekf"
    (handles[replay.estimator],) = axis.plot(series.t, np.degrees(series.error[:, row]), lw=1.2 if wide else 0.7,
                                             color=COLORS.get(replay.estimator), zorder=3 if wide else 2)
    return handles


def _error_range(replays: Sequence[ReplayResult], row: int) -> tuple[float, float]:
    """Symmetric limits holding RANGE_PERCENTILE of the scored errors of every estimator whose RMS
    error is within RANGE_RMS_FACTOR of the lowest: a filter degrees off does not squash the others."""
    scored = [np.abs(np.degrees(r.series.error[r.series.t >= SCORING_SKIP, row])) for r in replays]
    scored = [errors[np.isfinite(errors)] for errors in scored]
    rms = [float(np.sqrt(np.mean(errors ** 2))) for errors in scored if errors.size]
    if not rms:
        return -1.0, 1.0
    spread = [float(np.percentile(errors, RANGE_PERCENTILE)) for errors in scored
              if errors.size and np.sqrt(np.mean(errors ** 2)) <= RANGE_RMS_FACTOR * min(rms)]
    limit = 1.15 * max(spread) or 1.0
    return -limit, limit


def plot_rmse(rows: Sequence[Row], path: Path) -> None:
    """Pooled tilt RMSE per terrain and estimator, one panel per contact and grade, with the
    issue's RMSE limit of the grade."""
    clean = [r for r in rows if r.fault == "none" and r.array == "imu_only"]
    if not clean:
        return
    contacts = list(dict.fromkeys(r.contact for r in clean))
    grades = list(dict.fromkeys(r.grade for r in clean))
    terrains = list(dict.fromkeys(r.terrain for r in clean))
    names = list(dict.fromkeys(r.estimator for r in clean))
    table = {(r.terrain, r.contact, r.grade, r.estimator): r.tilt_rmse_deg for r in clean}
    figure, axes = new_figure(len(contacts), len(grades), (3.6 * len(grades) + 1.8, 2.8 * len(contacts) + 0.6))
    width = 0.8 / len(names)
    low = min(table.values())
    for i, contact in enumerate(contacts):
        for j, grade in enumerate(grades):
            axis = axes[i, j]
            for k, name in enumerate(names):
                values = [table.get((t, contact, grade, name), np.nan) for t in terrains]
                axis.bar(np.arange(len(terrains)) + (k - (len(names) - 1) / 2) * width, values, width,
                         label=name, color=COLORS.get(name))
            axis.axhline(rmse_target(grade), color="k", lw=0.8, ls="--", label="ekf limit (each axis)")
            axis.set_xticks(np.arange(len(terrains)), terrains, fontsize=8)
            axis.set_yscale("log")
            axis.set_ylim(bottom=0.5 * low)
            axis.set_title(f"{contact}, {grade} IMU", fontsize=9)
            axis.grid(alpha=0.3, axis="y")
        axes[i, 0].set_ylabel("tilt RMSE (°)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside right center", fontsize=8)
    save_png(figure, path)


def plot_nees(replays: Sequence[ReplayResult], rows: Sequence[Row], path: Path) -> None:
    """EKF on the compliant, default-grade, IMU-only walks: NEES over time averaged over the runs of
    each terrain against its 95 % chi-square bounds, and each run's ANEES against the bounds of the
    average."""
    from estimators.scoring import anees_bounds

    def plotted(r: ReplayResult) -> bool:
        s = r.scenario
        return (r.estimator == "ekf" and s.fault == "none" and s.array == "imu_only" and s.contact == "compliant"
                and s.grade == "default")

    ekf = [r for r in replays if plotted(r) and r.series is not None and r.series.nees is not None]
    terrains = list(dict.fromkeys(r.scenario.terrain for r in ekf))
    if not terrains:
        return
    figure, axes = new_figure(1, 2, (11, 4.2))
    for terrain in terrains:
        runs = [r.series for r in ekf if r.scenario.terrain == terrain]
        length = min(len(s.nees) for s in runs)
        average = np.mean([s.nees[:length] for s in runs], axis=0)
        axes[0, 0].plot(runs[0].t[:length], average, lw=0.8, label=f"{terrain} ({runs_text(len(runs))})")
    low, high = anees_bounds(min(sum(r.scenario.terrain == t for r in ekf) for t in terrains))
    for bound in (low, high):
        axes[0, 0].axhline(bound, color="k", ls="--", lw=0.8)
    axes[0, 0].set_yscale("log")
    axes[0, 0].set_xlabel("time (s)")
    axes[0, 0].set_ylabel("NEES of roll and pitch, mean over runs")
    axes[0, 0].set_title("EKF, compliant, default IMU; dashed: 95 % bounds of the mean", fontsize=9)
    axes[0, 0].legend(fontsize=8)
    for k, terrain in enumerate(terrains):
        row = next(r for r in rows if r.key == (terrain, "compliant", "default", "imu_only", "none")
                   and r.estimator == "ekf")
        per_run = [r.metrics["anees_tilt"] for r in replays if plotted(r) and r.scenario.terrain == terrain]
        axes[0, 1].vlines(k, *row.anees_bounds, color="0.6", lw=6, zorder=1)
        axes[0, 1].scatter(np.full(len(per_run), k), per_run, s=12, color="C0", alpha=0.6, zorder=2)
        axes[0, 1].plot(k, row.anees_tilt, "s", color="C3", zorder=3)
    axes[0, 1].axhline(2.0, color="k", lw=0.5)
    axes[0, 1].set_xticks(range(len(terrains)), terrains)
    axes[0, 1].set_xlim(-0.5, len(terrains) - 0.5)
    axes[0, 1].set_yscale("log")
    axes[0, 1].set_ylabel("ANEES of roll and pitch")
    axes[0, 1].set_title("dots: runs; square: their mean; grey bar: the mean's 95 % bounds", fontsize=9)
    save_png(figure, path)


def write_plots(result: BenchResult, folder: Path) -> None:
    rows = summary_rows(result.replays)
    for terrain in dict.fromkeys(r.scenario.terrain for r in result.replays):
        plot_errors(result.replays, terrain, folder / f"estimators_error_{terrain}.png")
    plot_rmse(rows, folder / "estimators_rmse.png")
    plot_nees(result.replays, rows, folder / "estimators_nees.png")


# --- entry points --------------------------------------------------------------------------------

def write(result: BenchResult, checks: Sequence[Check], folder: Path) -> None:
    """results.md, results.csv, results.json and the plots, in `folder`."""
    folder = Path(folder)
    write_plots(result, folder)
    write_atomically(folder / "results.csv", csv_text(run_rows(result.replays)).encode())
    write_atomically(folder / "results.json", json_text(result, checks).encode())
    write_atomically(folder / "results.md", ("# Estimator benchmark\n\n" + markdown(result, checks, ".")).encode())


def write_docs(result: BenchResult, checks: Sequence[Check], docs: Path = DOCS) -> None:
    """docs/results/estimators.{md,csv,json}, docs/img/estimators_*.png, then docs/results.md."""
    write_plots(result, docs / "img")
    write_atomically(docs / "results" / "estimators.csv", csv_text(run_rows(result.replays)).encode())
    write_atomically(docs / "results" / "estimators.json", json_text(result, checks).encode())
    write_atomically(docs / "results" / ESTIMATORS_FRAGMENT,
                      ("## Estimators\n\n" + markdown(result, checks, "img")).encode())
    write_results_page(docs)


ESTIMATORS_FRAGMENT = "estimators.md"


def write_fragment(name: str, text: str, docs: Path = DOCS) -> None:
    """A benchmark's section of docs/results.md: docs/results/<name>, included by `results_page`."""
    write_atomically(docs / "results" / name, text.encode())


def results_page(docs: Path = DOCS) -> str:
    """docs/results/estimators.md first, then every other fragment docs/results/*.md by name,
    verbatim."""
    folder = docs / "results"
    fragments = sorted(folder.glob("*.md"), key=lambda path: (path.name != ESTIMATORS_FRAGMENT, path.name))
    parts = ["# Results\n\nGenerated by `make bench` (tests/benchmarks); do not edit by hand. Each section is a "
             "fragment of `docs/results/`, included verbatim: the estimators' from `testbed/bench_report.py`, the "
             "others from their benchmarks.\n"]
    parts += [path.read_text(encoding="utf-8").rstrip("\n") + "\n" for path in fragments]
    return "\n".join(parts)


def write_results_page(docs: Path = DOCS) -> None:
    write_atomically(docs / "results.md", results_page(docs).encode())


if __name__ == "__main__":
    # `make bench` runs this after every benchmark wrote its fragment.
    write_results_page()
    print(f"wrote {DOCS / 'results.md'}")
