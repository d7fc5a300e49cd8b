"""Per-run metrics, accumulated tick by tick from ground truth, written as JSON.

Keys are floats in SI units except where the key says `_deg`; null where a metric does not apply.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from testbed.contact import FootContacts

WEIGHT_WINDOW = 1.0   # s, weight_support_ratio averages over the last second of the run


class StandMetrics:
    """fell, weight_support_ratio, realtime_factor, sim_steps, wall_s."""

    def __init__(self, weight: float, time_step: float, duration: float):
        self.weight = weight
        self.window_start = duration - WEIGHT_WINDOW - 0.5 * time_step
        self.fell = False
        self._normal_sum = 0.0
        self._normal_count = 0

    def add_contacts(self, t: float, contacts: FootContacts) -> None:
        if t >= self.window_start:
            self._normal_sum += float(contacts.normal_forces.sum())
            self._normal_count += 1

    def summary(self, sim_time: float, wall_s: float, sim_steps: int) -> dict:
        ratio = self._normal_sum / self._normal_count / self.weight if self._normal_count else None
        return {
            "fell": self.fell,
            "weight_support_ratio": ratio,
            "realtime_factor": sim_time / wall_s if wall_s > 0 else None,
            "sim_steps": sim_steps,
            "sim_time_s": sim_time,
            "wall_s": wall_s,
        }


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return _clean(value.item())
    if isinstance(value, dict):
        return {key: _clean(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(item) for item in value]
    return value


def write_metrics(path: str | Path, metrics: dict) -> None:
    """Write atomically: a temporary file in the same folder, renamed over the target."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(handle, "w") as stream:
            json.dump(_clean(metrics), stream, indent=2, sort_keys=True)
            stream.write("\n")
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
