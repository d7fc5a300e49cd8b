"""Small helpers of the estimator tests."""

from __future__ import annotations

import numpy as np

from estimators.base import Estimate
from estimators.scoring import estimate_arrays, score
from tests.estimators.synthetic import Trajectory


def tilt_errors_deg(estimates: list[Estimate], trajectory: Trajectory) -> np.ndarray:
    """(N, 2) roll and pitch errors in degrees, estimates matched to truth by time."""
    index = np.searchsorted(trajectory.t, [e.t for e in estimates])
    truth = trajectory.roll_pitch_yaw[index, :2]
    return np.degrees(np.array([[e.roll, e.pitch] for e in estimates]) - truth)


def metrics(estimates: list[Estimate], trajectory: Trajectory) -> dict:
    return score(estimate_arrays(estimates), trajectory.t, trajectory.rotation)


def tilt_rmse_deg(estimates: list[Estimate], trajectory: Trajectory) -> float:
    """RMS of roll and pitch errors together, first second excluded."""
    m = metrics(estimates, trajectory)
    return float(np.hypot(m["roll_rmse_deg"], m["pitch_rmse_deg"]) / np.sqrt(2))


def all_finite(estimates: list[Estimate]) -> bool:
    fields = ("quaternion", "attitude_cov", "gyro_bias", "gyro_bias_cov", "terrain_roll", "terrain_pitch",
              "body_height", "terrain_cov")
    for estimate in estimates:
        if not np.isfinite([estimate.t, estimate.roll, estimate.pitch, estimate.yaw]).all():
            return False
        for name in fields:
            value = getattr(estimate, name)
            if value is not None and not np.isfinite(value).all():
                return False
    return True
