"""Gait timing against the gait table, the stance line and the elliptic swing of the paper."""

import numpy as np
import pytest

from testbed import config
from testbed.gait import GAIT_TABLE, GaitGenerator, Twist
from testbed.kinematics import LegGeometry, nominal_stance

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)
NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
DT = 0.001
# Neighbours around the body (legs numbered counter-clockwise, 0-based here).
ADJACENT = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0)]


def swing_schedule(name: str, cycles: int = 3, period: float = 1.2) -> tuple[np.ndarray, np.ndarray]:
    gait = GaitGenerator(name, NEUTRAL, period, 0.03)
    t = np.arange(1, int(cycles * period / DT) + 1) * DT
    return t, np.array([gait.scheduled_swing(ti) for ti in t])


@pytest.mark.parametrize("name, duty", [("tripod", 1 / 2), ("ripple", 2 / 3), ("wave", 5 / 6)])
def test_duty_factor_of_every_leg_matches_the_table(name, duty):
    _, swing = swing_schedule(name)
    assert GAIT_TABLE[name][0] == pytest.approx(duty)
    assert np.allclose(1.0 - swing.mean(axis=0), duty, atol=2e-3)


@pytest.mark.parametrize("name", ["tripod", "ripple", "wave"])
def test_swing_starts_at_the_tabled_phase_offsets(name):
    period = 1.2
    t, swing = swing_schedule(name, period=period)
    starts = t[1:][np.diff(swing.astype(int), axis=0).T[0] == 1]   # leg 1's swing starts
    for leg in range(6):
        leg_starts = t[1:][np.diff(swing[:, leg].astype(int)) == 1]
        offsets = np.mod(leg_starts / period, 1.0)
        assert np.allclose(offsets, GAIT_TABLE[name][1][leg], atol=2e-3) or \
            np.allclose(np.mod(offsets - GAIT_TABLE[name][1][leg] + 0.5, 1.0) - 0.5, 0.0, atol=2e-3)
    assert len(starts) >= 2


def test_tripod_alternates_135_and_246_and_no_neighbours_swing_together():
    _, swing = swing_schedule("tripod")
    assert np.array_equal(swing[:, 0], swing[:, 2]) and np.array_equal(swing[:, 0], swing[:, 4])
    assert np.array_equal(swing[:, 1], swing[:, 3]) and np.array_equal(swing[:, 1], swing[:, 5])
    assert not np.any(swing[:, 0] & swing[:, 1])
    for a, b in ADJACENT:
        assert not np.any(swing[:, a] & swing[:, b])


@pytest.mark.parametrize("name, most", [("ripple", 2), ("wave", 1)])
def test_ripple_and_wave_lift_at_most_their_share_of_legs(name, most):
    _, swing = swing_schedule(name)
    assert swing.sum(axis=1).max() == most
    for a, b in ADJACENT:
        assert not np.any(swing[:, a] & swing[:, b])


def test_stance_is_a_straight_line_of_one_step_and_swing_an_ellipse():
    speed, period, height = 0.1, 1.0, 0.03
    gait = GaitGenerator("tripod", NEUTRAL, period, height)
    gait.state.feet[:] = NEUTRAL
    command = Twist(vx=speed)
    feet, swinging = [], []
    for k in range(1, 3001):
        feet.append(gait.step(k * DT, DT, command))
        swinging.append(gait.state.swinging.copy())
    feet, swinging = np.array(feet)[1000:], np.array(swinging)[1000:]   # past the first cycle
    leg = 0
    stance = ~swinging[:, leg]
    # one stance: consecutive stance samples of leg 1
    runs = np.split(np.arange(len(stance)), np.flatnonzero(np.diff(stance.astype(int))) + 1)
    stance_run = next(r for r in runs if stance[r[0]] and len(r) > 400)
    path = feet[stance_run, leg]
    step = speed * 0.5 * period
    assert path[0, 0] - path[-1, 0] == pytest.approx(step, rel=0.01)            # backwards by one step
    assert np.ptp(path[:, 1]) < 1e-12 and np.ptp(path[:, 2]) < 1e-12            # along a straight line
    swing_run = next(r for r in runs if swinging[r[0], leg] and len(r) > 400)
    arc = feet[swing_run, leg]
    centre_x = NEUTRAL[leg, 0]
    # (x - xc)^2 / (L/2)^2 + (z - z0)^2 / H^2 = 1: the paper's Figure 4 ellipse
    ellipse = ((arc[:, 0] - centre_x) / (step / 2)) ** 2 + ((arc[:, 2] - NEUTRAL[leg, 2]) / height) ** 2
    assert np.allclose(ellipse, 1.0, atol=0.02)
    assert arc[:, 2].max() == pytest.approx(NEUTRAL[leg, 2] + height, abs=1e-4)


def test_stop_finishes_swings_then_keeps_all_feet_down():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.03)
    for k in range(1, 1300):
        gait.step(k * DT, DT, Twist(vx=0.1))
    gait.stop()
    for k in range(1300, 3000):
        gait.step(k * DT, DT, Twist())
    assert not gait.state.swinging.any()
    assert np.allclose(gait.state.feet[:, 2], NEUTRAL[:, 2])
