"""The benchmark's error plot: one walk, each estimator once, a y range set by the scored errors."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from testbed.tools.bench import ReplayResult, Scenario, Series
from testbed.tools.bench_report import error_figure

T = np.arange(0.0, 5.0, 0.01)


def walk(estimator: str, seed: int, error_deg: float, sigma_deg: np.ndarray | None = None) -> ReplayResult:
    error = np.radians(np.column_stack([error_deg * np.sin(T), -error_deg * np.cos(T)]))
    sigma = None if sigma_deg is None else np.radians(np.column_stack([sigma_deg, sigma_deg]))
    return ReplayResult(Scenario("step", seed, 5.0), estimator, {}, {}, 0.0, 0.0, Series(T, error, sigma, None))


def test_one_seed_each_estimator_once_and_the_start_up_band_cut_off():
    start_up_band = np.where(T < 1.0, 30.0, 0.1)        # deg, the EKF's first 3-sigma band is +-30 deg
    replays = [walk(name, seed, error, start_up_band if name == "ekf" else None)
               for seed in (3, 1, 2) for name, error in (("ekf", 0.2), ("vqf", 0.5), ("madgwick", 0.4))]
    figure = error_figure(replays, "step")
    try:
        roll_axis = figure.axes[0]
        labels = [text.get_text() for text in roll_axis.get_legend().get_texts()]
        assert sorted(labels) == ["ekf", "ekf ±3σ", "madgwick", "vqf"]
        assert "seed 1" in roll_axis.get_title()
        low, high = roll_axis.get_ylim()
        assert 0.5 < high <= 1.15 * 0.5 + 1e-9 and low == -high     # vqf's 0.5 deg sets it, not the 30 deg band
    finally:
        plt.close(figure)


def test_no_figure_without_series_of_the_terrain():
    assert error_figure([walk("ekf", 0, 0.2)], "flat") is None
