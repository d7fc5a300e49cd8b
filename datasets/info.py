"""`testbed info RUN.mcap`: what a recording holds, in a few lines of text."""

from __future__ import annotations

import json
from pathlib import Path

from datasets.reader import Recording, read_recording

PACKAGE = "hexapod-testbed"
METRIC_ORDER = ("roll_rmse_deg", "pitch_rmse_deg", "tilt_error_max_deg", "slope_error_deg", "height_est_rmse_m",
                "anees_tilt", "fell", "left_terrain", "weight_support_ratio", "min_stability_margin_m", "distance_m",
                "realtime_factor", "sim_time_s", "wall_s")


LOG_TIME_SLACK_S = 1.0      # s: messages may be stamped this far past the configured duration


def describe(path: str | Path) -> str:
    """UserError (exit 2) for a testbed file cut before its config or whose config does not read."""
    recording = read_recording(path, topics=())
    if recording.run_info() or "config" in recording.metadata or recording.truncated:
        recording.config()
    return "\n".join(_header(recording) + _topics(recording) + _metrics(recording))


def _state(recording: Recording) -> str:
    if recording.truncated is not None:
        return f"TRUNCATED: {recording.truncated}"
    limit = recording.config().run.duration + LOG_TIME_SLACK_S
    if recording.duration_s() > limit:
        return (f"DAMAGED: messages stamped up to {recording.duration_s():.6g} s, beyond the configured "
                f"{limit - LOG_TIME_SLACK_S:g} s")
    return "complete"


def _header(recording: Recording) -> list[str]:
    run = recording.run_info()
    size = recording.path.stat().st_size
    duration = recording.duration_s()
    state = _state(recording) if "config" in recording.metadata else (
        "complete" if recording.truncated is None else f"TRUNCATED: {recording.truncated}")
    lines = [f"{recording.path}: {_megabytes(size)} ({state})"]
    if run:
        lines.append(f"terrain {run.get('terrain', '?')}, estimator {run.get('estimator', '?')}, "
                     f"gait {run.get('gait', '?')}, seed {run.get('seed', '?')}, "
                     f"configured duration {run.get('duration_s', '?')} s, recorded {run.get('created_utc', '?')}")
        lines += _plugins(run.get("parts"))
    else:
        lines.append("no testbed run description (not written by testbed run)")
    per_second = f", {size / duration / 1000:.0f} kB per simulated second" if duration > 0 else ""
    if "config" in recording.metadata and duration > recording.config().run.duration + LOG_TIME_SLACK_S:
        duration = 0.0      # a damaged time stamp says nothing of the run's length
    lines.append(f"duration {duration:.3f} s of simulated time, {recording.message_count()} messages{per_second}")
    error = recording.outcome().get("error")
    if error:
        lines.append(f"run stopped early: {error}")
    return lines


def _plugins(parts_json: str | None) -> list[str]:
    """One line per part that did not come from this package: its spec, file and hash, package."""
    try:
        parts = json.loads(parts_json) if parts_json else {}
    except json.JSONDecodeError:
        return ["parts: unreadable"]
    lines = []
    for kind, source in sorted(parts.items()) if isinstance(parts, dict) else ():
        if not isinstance(source, dict) or source.get("distribution") == PACKAGE:
            continue
        origin = source.get("distribution") and f"{source['distribution']} {source.get('version')}"
        digest = (source.get("module_sha256") or "")[:12]
        lines.append(f"plugin {kind}: {source.get('spec')} ({origin or source.get('module_file')}, sha256 {digest})")
    return lines


def _topics(recording: Recording) -> list[str]:
    lines = ["topics:"]
    width = max((len(name) for name in recording.topics), default=0)
    for name, stats in sorted(recording.topics.items()):
        rate = f"{stats.rate_hz:9.1f} Hz" if stats.rate_hz is not None else " " * 12
        lines.append(f"  {name:<{width}}  {stats.count:8d} msgs {rate}  {stats.schema}")
    return lines


def _metrics(recording: Recording) -> list[str]:
    metrics = recording.metrics()
    if metrics is None:
        return ["metrics: none (the run did not finish writing this file)"]
    keys = [key for key in METRIC_ORDER if key in metrics] + sorted(set(metrics) - set(METRIC_ORDER))
    return ["metrics:"] + [f"  {key}: {_format(metrics[key])}" for key in keys]


def _format(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "null" if value is None else str(value)


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.2f} MB"
