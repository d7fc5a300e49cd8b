"""Estimator metrics of a recording, through the function the live run scores with.

A live run scores with `testbed.runtime.metrics.score_estimates` from the truth of every physics step
(time, body quaternion and position, foot centres and contacts). The recorder writes exactly those
numbers, losslessly, at every step (`/truth/pose` and `/truth/feet`), so a replay that calls the
same function on them reproduces the live metrics exactly (same numbers, same operations).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimators.base import Estimate
from estimators.scoring import EstimateArrays
from testbed.runtime.config import Config
from testbed.runtime.metrics import score_estimates


@dataclass(frozen=True)
class ScoringTruth:
    """The truth of every physics step that scoring reads."""
    t: np.ndarray                   # (N,) s, simulation time
    quaternion: np.ndarray          # (N, 4) world_from_body, x, y, z, w
    body_position: np.ndarray       # (N, 3) m, world
    foot_positions: np.ndarray      # (N, 6, 3) m, world, foot sphere centres
    foot_contact: np.ndarray        # (N, 6) bool


def score_run(config: Config, truth: ScoringTruth, estimates: Sequence[Estimate] | EstimateArrays) -> dict:
    """Metrics `estimators.scoring.METRIC_KEYS` of the estimates (or their columns), scored exactly
    as the live run."""
    return score_estimates(config, truth.t, truth.quaternion, truth.body_position, truth.foot_positions,
                           truth.foot_contact, estimates if isinstance(estimates, EstimateArrays) else list(estimates))
