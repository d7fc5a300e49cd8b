"""The gyro bias step detector's window test (estimators.fusion.BiasStepDetector)."""

import copy
import math

import numpy as np
import pytest

from testbed.model import spatial as rot
from estimators.fusion import BIAS, THETA, BiasStepDetector, horizontal_basis, turn_angle

WINDOW = 1.0            # s
PROBABILITY = 0.9999    # threshold 18.42 at 2 dof, 36.84 for a disturbed window
MIN_DRIFT = 0.005       # rad/s
SCALE_STD = 0.036       # of the turn: the consumer IMU's 3 % scale and 2 % cross-axis errors
LEVEL = rot.quaternion_from_euler(0.0, 0.0, 0.0)


def new_detector() -> BiasStepDetector:
    return BiasStepDetector(WINDOW, PROBABILITY, MIN_DRIFT, SCALE_STD)


def window_result(statistic: float, rate: float, disturbed: bool, detector: BiasStepDetector | None = None,
                  start: float = 0.0, pitched: float = 0.0):
    """One window from `start` (s), level at its start and pitched by `pitched` (rad) at its end,
    whose summed tilt corrections drift at `rate` (rad/s) along x with a chi-square `statistic`
    (of the white sum alone): the detector's verdict at its end."""
    detector = detector or new_detector()
    detector.check(start, LEVEL)
    drift = rate * WINDOW
    detector.add(np.array([drift, 0.0, 0.0]), drift**2 / statistic * np.eye(3))
    if disturbed:
        detector.disturb()
    return detector.check(start + WINDOW, rot.quaternion_from_euler(0.0, pitched, 0.0))


def test_thresholds_are_the_chi_square_quantile_and_its_square_probability():
    detector = new_detector()
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
    detector = new_detector()
    assert window_result(20.4, 0.0036, disturbed=True, detector=detector) is None
    assert window_result(20.4, 0.0036, disturbed=False, detector=detector, start=WINDOW) is not None
    assert detector.detections == 1


def test_turn_angle_is_the_rotation_between_two_attitudes():
    assert turn_angle(LEVEL, LEVEL) == 0.0
    assert turn_angle(LEVEL, rot.quaternion_from_euler(0.0, 0.17, 0.0)) == pytest.approx(0.17)
    assert turn_angle(rot.quaternion_from_euler(0.0, 0.0, 3.0), rot.quaternion_from_euler(0.0, 0.0, -3.0)) \
        == pytest.approx(2 * math.pi - 6.0)


def test_the_scale_errors_of_a_windows_turn_are_no_bias_step():
    """Pitching onto a 10 deg ramp within the window: a 3.6 % scale error alone drifts the tilt by
    6 mrad, more than the 5 mrad that with a white sum of statistic 30 would be a bias step."""
    ramp = math.radians(10.0)
    assert window_result(statistic=30.0, rate=0.005, disturbed=False) is not None
    assert window_result(statistic=30.0, rate=0.005, disturbed=False, pitched=ramp) is None
    # A drift five times the turn's scale error still raises it.
    assert window_result(statistic=1000.0, rate=5 * SCALE_STD * ramp, disturbed=False, pitched=ramp) is not None


def test_an_alarm_widens_the_bias_on_every_axis_and_the_tilt_where_the_tilt_sees_it(runs):
    """The tilt test sees the bias's horizontal part; a step is as likely to have moved the
    vertical part, whose variance widens as much (the feet then teach it), while the tilt's
    widens in the horizontal directions only (a turn about the vertical is no tilt)."""
    _, ran = runs.run("ekf", 0)
    ekf = copy.deepcopy(ran)
    up = np.array(rot.up_in_body(rot.quaternion_from_euler(0.3, -0.2, 1.0)))
    bias_before, tilt_before = ekf.P[BIAS, BIAS].copy(), ekf.P[THETA, THETA].copy()
    rate = 0.02     # rad/s, above bias_fault_std
    ekf._open_bias(up, rate, WINDOW)
    bias_widened, tilt_widened = ekf.P[BIAS, BIAS] - bias_before, ekf.P[THETA, THETA] - tilt_before
    basis = horizontal_basis(up)
    assert bias_widened == pytest.approx(rate**2 * np.eye(3), rel=1e-9)
    assert up @ tilt_widened @ up == pytest.approx(0.0, abs=1e-15)
    assert basis @ tilt_widened @ basis.T == pytest.approx((rate * WINDOW)**2 * np.eye(2), rel=1e-9)
