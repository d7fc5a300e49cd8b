"""Still windows (estimators/stillness.py): the mean specific force of a body that does not move."""

from __future__ import annotations

import math

import numpy as np

from estimators.stillness import StillWindow

DT = 0.005
GRAVITY = np.array([0.0, 0.1, 9.81])


def window() -> StillWindow:
    return StillWindow(duration=0.05, max_rate=math.radians(1.0), max_force_change=0.1)


def test_a_still_window_gives_its_mean_force_once():
    still = window()
    rng = np.random.default_rng(0)
    forces = GRAVITY + rng.normal(0.0, 0.02, (10, 3))
    results = [still.add(DT, np.zeros(3), force, np.zeros(3)) for force in forces]
    assert all(r is None for r in results[:-1])
    np.testing.assert_allclose(results[-1].force, forces.mean(axis=0), atol=1e-12)
    # The next window starts afresh: no interval is used twice.
    assert still.add(DT, np.zeros(3), GRAVITY, np.zeros(3)) is None


def test_a_turn_or_a_shake_restarts_the_window():
    still = window()
    for _ in range(9):
        still.add(DT, np.zeros(3), GRAVITY, np.zeros(3))
    turning = np.array([math.radians(2.0) * DT, 0.0, 0.0])         # 2 deg/s
    assert still.add(DT, turning, GRAVITY, np.zeros(3)) is None
    for _ in range(9):
        assert still.add(DT, np.zeros(3), GRAVITY, np.zeros(3)) is None
    assert still.add(DT, np.zeros(3), GRAVITY + [0.0, 0.0, 0.5], np.zeros(3)) is None     # a 0.5 m/s^2 jolt
    results = [still.add(DT, np.zeros(3), GRAVITY, np.zeros(3)) for _ in range(10)]
    assert results[-1] is not None and all(r is None for r in results[:-1])


def test_a_still_window_gives_the_gyro_mean_reading():
    still = window()
    rng = np.random.default_rng(1)
    bias = np.array([0.01, -0.02, 0.03])                            # rad/s, the filter's estimate
    residual = rng.normal(0.0, 1e-3, (10, 3))                       # rad/s, the reading after it
    results = [still.add(DT, rate * DT, GRAVITY, bias) for rate in residual]
    np.testing.assert_allclose(results[-1].rate, bias + residual.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(results[-1].force, GRAVITY, atol=1e-12)
