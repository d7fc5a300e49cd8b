"""Estimator metrics of a recording, through the scorer the live run scores with.

A live run scores with `estimators.scoring.StreamingScore` from the truth of every physics step
(time, body quaternion and position, foot centres and contacts). The recorder writes exactly those
numbers, losslessly, at every step (`/truth/pose` and `/truth/feet`), so a replay that gives the
same scorer the same numbers reproduces the live metrics exactly (same numbers, same operations),
whether it gives them whole (`score_run`) or part by part as the estimates come (`score_as_they_come`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from estimators.base import Estimate
from estimators.scoring import EstimateArrays, StreamingScore
from testbed.runtime.config import Config
from testbed.runtime.metrics import estimator_metrics, score_estimates


@dataclass(frozen=True)
class ScoringTruth:
    """The truth of every physics step that scoring reads."""
    t: np.ndarray                   # (N,) s, simulation time
    quaternion: np.ndarray          # (N, 4) world_from_body, x, y, z, w
    body_position: np.ndarray       # (N, 3) m, world
    foot_positions: np.ndarray      # (N, 6, 3) m, world, foot sphere centres
    foot_contact: np.ndarray        # (N, 6) bool

    def steps(self, first: int, stop: int) -> tuple[np.ndarray, ...]:
        """The columns of the steps [first, stop), in the order `StreamingScore.add_truth` takes them."""
        return (self.t[first:stop], self.quaternion[first:stop], self.body_position[first:stop],
                self.foot_positions[first:stop], self.foot_contact[first:stop])


def score_run(config: Config, truth: ScoringTruth, estimates: Sequence[Estimate] | EstimateArrays) -> dict:
    """Metrics `estimators.scoring.METRIC_KEYS` of the estimates (or their columns), scored exactly
    as the live run."""
    return score_estimates(config, truth.t, truth.quaternion, truth.body_position, truth.foot_positions,
                           truth.foot_contact, estimates if isinstance(estimates, EstimateArrays) else list(estimates))


def score_as_they_come(config: Config, truth: ScoringTruth, parts: Iterable[EstimateArrays]) -> dict:
    """`score_run` of estimates that come in time-ordered parts: the truth up to each part's last
    time goes to the scorer after it, so that every block of truth is scored as soon as the
    estimates it scores have come, with the numbers of the whole (`StreamingScore`)."""
    scoring = StreamingScore(config.robot.foot_radius)
    added = 0
    for part in parts:
        scoring.add_estimates(part)
        if len(part.t):
            until = int(np.searchsorted(truth.t, part.t[-1], side="right"))
            scoring.add_truth(*truth.steps(added, until))
            added = max(added, until)
    scoring.add_truth(*truth.steps(added, len(truth.t)))
    return estimator_metrics(config, scoring)
