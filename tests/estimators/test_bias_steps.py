"""The gyro bias step detector's window test (estimators.fusion.BiasStepDetector)."""

import math

import numpy as np
import pytest

from testbed.model import spatial as rot
from estimators.fusion import BiasStepDetector

WINDOW = 1.0            # s
PROBABILITY = 0.9999    # threshold 18.42 at 2 dof, 36.84 for a disturbed window
MIN_DRIFT = 0.005       # rad/s
LEVEL = rot.quaternion_from_euler(0.0, 0.0, 0.0)


def window_result(statistic: float, rate: float, disturbed: bool, detector: BiasStepDetector | None = None,
                  start: float = 0.0):
    """One window from `start` (s) whose summed tilt corrections drift at `rate` (rad/s) along x
    with a chi-square `statistic`: the detector's verdict at its end."""
    detector = detector or BiasStepDetector(WINDOW, PROBABILITY, MIN_DRIFT)
    detector.check(start, LEVEL)
    drift = rate * WINDOW
    detector.add(np.array([drift, 0.0, 0.0]), drift**2 / statistic * np.eye(3))
    if disturbed:
        detector.disturb()
    return detector.check(start + WINDOW, LEVEL)


def test_thresholds_are_the_chi_square_quantile_and_its_square_probability():
    detector = BiasStepDetector(WINDOW, PROBABILITY, MIN_DRIFT)
    assert detector.threshold == pytest.approx(-2.0 * math.log(1.0 - PROBABILITY))
    assert detector.disturbed_threshold == pytest.approx(2.0 * detector.threshold)


def test_an_undisturbed_excess_is_a_bias_step_with_its_drift_rate():
    assert window_result(statistic=20.0, rate=0.0036, disturbed=False) == pytest.approx((0.0036, WINDOW))
    assert window_result(statistic=17.0, rate=0.05, disturbed=False) is None


@pytest.mark.parametrize(("statistic", "rate", "moved"), [
    (20.4, 0.0036, False),      # slips on rough DART ground
    (20.4, 0.006, True),        # a drift the filter models as a bias step
    (63.0, 0.0027, True),       # a 0.5 rad/s bias step whose slipping feet reopen the velocity
    (17.0, 0.1, False),         # no excess at all
])
def test_a_disturbed_window_needs_a_modelled_drift_or_a_squared_probability(statistic, rate, moved):
    assert (window_result(statistic, rate, disturbed=True) is not None) == moved


def test_a_disturbance_counts_for_its_own_window_only():
    detector = BiasStepDetector(WINDOW, PROBABILITY, MIN_DRIFT)
    assert window_result(20.4, 0.0036, disturbed=True, detector=detector) is None
    assert window_result(20.4, 0.0036, disturbed=False, detector=detector, start=WINDOW) is not None
    assert detector.detections == 1
