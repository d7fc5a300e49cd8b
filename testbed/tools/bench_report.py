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
import tempfile
from collections.abc import Sequence
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from testbed.tools.bench import FAULT_RATIO_TARGET, BenchResult, Check, ReplayResult, Row, summary_rows

DOCS = Path(__file__).resolve().parents[2] / "docs"
METRIC_COLUMNS = ("roll_rmse_deg", "pitch_rmse_deg", "tilt_error_max_deg", "slope_error_deg", "height_est_rmse_m",
                  "anees_tilt")
COLORS = {"ekf": "C3", "ukf": "C1", "complementary": "C7", "madgwick": "C2", "mahony": "C4", "vqf": "C0"}
SCORING_SKIP = 1.0     # s, the first second is not scored (estimators.scoring.score's default skip)


# --- files ---------------------------------------------------------------------------------------

def _write_atomically(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def run_rows(replays: Sequence[ReplayResult]) -> list[dict]:
    """One row per replay: the scenario, the estimator, its metrics and its cost."""
    rows = []
    for r in replays:
        row = {"terrain": r.scenario.terrain, "seed": r.scenario.seed, "duration_s": r.scenario.duration,
               "fault": r.scenario.fault, "estimator": r.estimator}
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
                "workers": result.workers, "summary": [asdict(row) for row in summary_rows(result.replays)],
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

def _number(value: float | None, digits: int = 3, scale: float = 1.0) -> str:
    return "–" if value is None else f"{value * scale:.{digits}f}"


def terrain_table(rows: Sequence[Row], terrain: str) -> str:
    lines = ["| estimator | roll RMSE (°) | pitch RMSE (°) | max tilt error (°) | ANEES (bounds) | "
             "slope error max (°) | height RMS (mm) | cost (µs / simulated ms) |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        if row.terrain != terrain or row.fault != "none":
            continue
        anees = "–" if row.anees_tilt is None else \
            f"{row.anees_tilt:.2f} ({row.anees_bounds[0]:.2f}–{row.anees_bounds[1]:.2f})"
        name = f"**{row.estimator}**" if row.estimator == "ekf" else row.estimator
        lines.append(f"| {name} | {row.roll_rmse_deg:.3f} | {row.pitch_rmse_deg:.3f} | {row.tilt_error_max_deg:.2f} | "
                     f"{anees} | {_number(row.slope_error_deg, 2)} | {_number(row.height_est_rmse_m, 2, 1e3)} | "
                     f"{row.cost_us_per_ms:.1f} |")
    return "\n".join(lines)


def fault_table(rows: Sequence[Row]) -> str:
    table = {(r.terrain, r.fault, r.estimator): r for r in rows}
    faulty = [r for r in rows if r.fault != "none"]
    if not faulty:
        return ""
    lines = ["| terrain | fault | estimator | roll / pitch RMSE (°) | fault-free (°) | ratio | max tilt error (°) |",
             "|---|---|---|---|---|---|---|"]
    for row in faulty:
        clean = table.get((row.terrain, "none", row.estimator))
        ratio = "–" if clean is None else f"{row.tilt_rmse_deg / clean.tilt_rmse_deg:.2f}"
        reference = "–" if clean is None else f"{clean.roll_rmse_deg:.3f} / {clean.pitch_rmse_deg:.3f}"
        lines.append(f"| {row.terrain} | {row.fault} | {row.estimator} | {row.roll_rmse_deg:.3f} / "
                     f"{row.pitch_rmse_deg:.3f} | {reference} | {ratio} | {row.tilt_error_max_deg:.2f} |")
    return "\n".join(lines)


def checks_table(checks: Sequence[Check]) -> str:
    lines = ["| target | measured | met |", "|---|---|---|"]
    lines += [f"| {c.what} | {c.detail} | {'yes' if c.passed else '**no**'} |" for c in checks]
    return "\n".join(lines)


def cost_table(replays: Sequence[ReplayResult]) -> str:
    """Median update cost per sample type over every replay, per estimator."""
    kinds = ("ImuSample", "EncoderSample", "FootSample")
    lines = ["| estimator | IMU sample (µs) | encoder sample (µs) | foot sample (µs) | per simulated ms (µs) | "
             "CPU per simulated ms (µs) |", "|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r.estimator for r in replays):
        mine = [r for r in replays if r.estimator == name]
        medians = [np.median([r.cost[k]["median_us"] for r in mine if k in r.cost]) for k in kinds]
        lines.append(f"| {name} | " + " | ".join(f"{m:.1f}" for m in medians)
                     + f" | {np.median([r.cost_per_ms for r in mine]):.1f} | {np.median([r.cpu_per_ms for r in mine]):.1f} |")
    return "\n".join(lines)


def markdown(result: BenchResult, checks: Sequence[Check], image_folder: str) -> str:
    rows = summary_rows(result.replays)
    bench_set = result.bench_set
    terrains = list(dict.fromkeys(r.terrain for r in rows if r.fault == "none"))
    seeds = bench_set.seeds
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    parts = [
        f"Tripod walks of {bench_set.duration:g} s at the default 0.1 m/s, controller off, default compliant "
        f"contact, seeds {seeds[0]}–{seeds[-1]} ({len(seeds)} per terrain); every estimator replays the same "
        f"recorded sensor data; the first second is not scored. RMSE pooled over the seeds (RMS of every "
        f"sample); ANEES averaged over the runs with the 95 % chi-square bounds for that many runs (2 dof); "
        f"slope error: the largest over the runs after 2 s. Cost: the median wall time of one update of each "
        f"sample type times its rate (IMU 1 kHz, encoders 200 Hz, feet 250 Hz), median over the runs; the "
        f"CPU column is the replay's whole process time per simulated ms, which a busy machine inflates. "
        f"Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC on {platform.machine()} with "
        f"{os.cpu_count()} CPUs, load average {load:.1f}, {result.workers} worker processes, in "
        f"{result.wall_s / 60:.1f} min ({result.recorded} walks simulated, the rest from the dataset cache).",
        "### Targets (issue 5)", checks_table(checks)]
    for terrain in terrains:
        parts += [f"### {terrain}", terrain_table(rows, terrain),
                  f"![{terrain}: errors over time]({image_folder}/estimators_error_{terrain}.png)"]
    faults = fault_table(rows)
    if faults:
        parts += ["### Sensor faults", f"Fault-free reference: the same seeds and terrain without the fault. "
                  f"Target: the EKF's RMSE under {FAULT_RATIO_TARGET:g} times its fault-free value.", faults]
    parts += ["### Summary plots", f"![RMSE per estimator and terrain]({image_folder}/estimators_rmse.png)",
              f"![EKF NEES against the chi-square bounds]({image_folder}/estimators_nees.png)",
              "### Cost per update", cost_table(result.replays)]
    return "\n\n".join(parts) + "\n"


# --- plots ---------------------------------------------------------------------------------------

def _figure(rows: int, columns: int, size: tuple[float, float]):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(rows, columns, figsize=size, squeeze=False, constrained_layout=True)


def _save(figure, path: Path) -> None:
    import matplotlib.pyplot as plt
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    plt.close(figure)
    _write_atomically(path, buffer.getvalue())


def plot_errors(replays: Sequence[ReplayResult], terrain: str, path: Path) -> None:
    figure = error_figure(replays, terrain)
    if figure is not None:
        _save(figure, path)


def error_figure(replays: Sequence[ReplayResult], terrain: str):
    """Roll and pitch errors over time of one walk (the lowest seed with series): each estimator
    once, the EKF with its 3-sigma band. The y range is that of the scored errors (after the first
    second), so the sub-degree differences show; the start-up's wide band is cut off at it. None
    without series of that terrain."""
    walks = [r for r in replays if r.scenario.terrain == terrain and r.scenario.fault == "none" and r.series]
    if not walks:
        return None
    seed = min(r.scenario.seed for r in walks)
    mine = list({r.estimator: r for r in walks if r.scenario.seed == seed}.values())
    figure, axes = _figure(2, 1, (9, 5.5))
    for row, angle in enumerate(("roll", "pitch")):
        axis = axes[row, 0]
        scored_errors = [0.0]
        for replay in mine:
            series = replay.series
            error = np.degrees(series.error[:, row])
            scored = series.t >= SCORING_SKIP
            scored_errors.append(float(np.nanmax(np.abs(error[scored]), initial=0.0)))
            if replay.estimator == "ekf" and series.sigma is not None:
                band = 3 * np.degrees(series.sigma[:, row])
                scored_errors.append(float(np.nanmax(band[scored], initial=0.0)))
                axis.fill_between(series.t, -band, band, color=COLORS["ekf"], alpha=0.15, label="ekf ±3σ")
            wide = replay.estimator == "ekf"
            axis.plot(series.t, error, lw=1.2 if wide else 0.7, color=COLORS.get(replay.estimator),
                      label=replay.estimator, zorder=3 if wide else 2)
        limit = 1.15 * max(scored_errors) or 1.0
        axis.set_ylim(-limit, limit)
        axis.axvline(SCORING_SKIP, color="k", lw=0.5, ls=":")
        axis.set_ylabel(f"{angle} error (°)")
        axis.grid(alpha=0.3)
    axes[0, 0].set_title(f"{terrain}, seed {seed}: estimate − truth (first second not scored)")
    axes[1, 0].set_xlabel("time (s)")
    axes[0, 0].legend(ncol=4, fontsize=8, loc="upper right")
    return figure


def plot_rmse(rows: Sequence[Row], path: Path) -> None:
    """Pooled roll and pitch RMSE per terrain and estimator, with the 0.3 deg target."""
    clean = [r for r in rows if r.fault == "none"]
    terrains = list(dict.fromkeys(r.terrain for r in clean))
    names = list(dict.fromkeys(r.estimator for r in clean))
    table = {(r.terrain, r.estimator): r for r in clean}
    figure, axes = _figure(1, 2, (11, 4))
    width = 0.8 / len(names)
    for column, angle in enumerate(("roll", "pitch")):
        axis = axes[0, column]
        for k, name in enumerate(names):
            values = [getattr(table[(t, name)], f"{angle}_rmse_deg") if (t, name) in table else np.nan
                      for t in terrains]
            axis.bar(np.arange(len(terrains)) + (k - (len(names) - 1) / 2) * width, values, width,
                     label=name, color=COLORS.get(name))
        axis.axhline(0.3, color="k", lw=0.8, ls="--", label="target 0.3°")
        axis.set_xticks(np.arange(len(terrains)), terrains)
        axis.set_ylabel(f"{angle} RMSE (°)")
        axis.set_yscale("log")
        axis.grid(alpha=0.3, axis="y")
    axes[0, 1].legend(fontsize=8)
    _save(figure, path)


def plot_nees(replays: Sequence[ReplayResult], rows: Sequence[Row], path: Path) -> None:
    """EKF: NEES over time averaged over the runs of each terrain against its 95 % chi-square
    bounds, and each run's ANEES against the bounds of the average."""
    from estimators.scoring import anees_bounds

    ekf = [r for r in replays if r.estimator == "ekf" and r.scenario.fault == "none" and r.series is not None
           and r.series.nees is not None]
    terrains = list(dict.fromkeys(r.scenario.terrain for r in ekf))
    if not terrains:
        return
    figure, axes = _figure(1, 2, (11, 4))
    for terrain in terrains:
        runs = [r.series for r in ekf if r.scenario.terrain == terrain]
        length = min(len(s.nees) for s in runs)
        mean = np.mean([s.nees[:length] for s in runs], axis=0)
        axes[0, 0].plot(runs[0].t[:length], mean, lw=0.8, label=f"{terrain} ({len(runs)} runs)")
    low, high = anees_bounds(min(sum(r.scenario.terrain == t for r in ekf) for t in terrains))
    for bound in (low, high):
        axes[0, 0].axhline(bound, color="k", ls="--", lw=0.8)
    axes[0, 0].set_yscale("log")
    axes[0, 0].set_xlabel("time (s)")
    axes[0, 0].set_ylabel("NEES of roll and pitch, mean over runs")
    axes[0, 0].set_title("95 % bounds for the mean of that many runs (dashed)")
    axes[0, 0].legend(fontsize=8)
    for k, terrain in enumerate(terrains):
        row = next(r for r in rows if r.terrain == terrain and r.fault == "none" and r.estimator == "ekf")
        per_run = [r.metrics["anees_tilt"] for r in replays if r.estimator == "ekf" and r.scenario.fault == "none"
                   and r.scenario.terrain == terrain]
        axes[0, 1].scatter(np.full(len(per_run), k), per_run, s=12, color="C0", alpha=0.6)
        axes[0, 1].vlines(k + 0.15, *row.anees_bounds, color="k", lw=2)
        axes[0, 1].plot(k, row.anees_tilt, "s", color="C3")
    axes[0, 1].axhline(2.0, color="k", lw=0.5)
    axes[0, 1].set_xticks(range(len(terrains)), terrains)
    axes[0, 1].set_yscale("log")
    axes[0, 1].set_ylabel("ANEES (dots: runs; square: their mean; bar: its 95 % bounds)")
    _save(figure, path)


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
    _write_atomically(folder / "results.csv", csv_text(run_rows(result.replays)).encode())
    _write_atomically(folder / "results.json", json_text(result, checks).encode())
    _write_atomically(folder / "results.md", ("# Estimator benchmark\n\n" + markdown(result, checks, ".")).encode())


def write_docs(result: BenchResult, checks: Sequence[Check], docs: Path = DOCS) -> None:
    """docs/results/estimators.{md,csv,json}, docs/img/estimators_*.png, then docs/results.md."""
    write_plots(result, docs / "img")
    _write_atomically(docs / "results" / "estimators.csv", csv_text(run_rows(result.replays)).encode())
    _write_atomically(docs / "results" / "estimators.json", json_text(result, checks).encode())
    _write_atomically(docs / "results" / ESTIMATORS_FRAGMENT,
                      ("## Estimators\n\n" + markdown(result, checks, "img")).encode())
    write_results_page(docs)


ESTIMATORS_FRAGMENT = "estimators.md"


def write_fragment(name: str, text: str, docs: Path = DOCS) -> None:
    """A benchmark's section of docs/results.md: docs/results/<name>, included by `results_page`."""
    _write_atomically(docs / "results" / name, text.encode())


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
    _write_atomically(docs / "results.md", results_page(docs).encode())


if __name__ == "__main__":
    # `make bench` runs this after every benchmark wrote its fragment.
    write_results_page()
    print(f"wrote {DOCS / 'results.md'}")
