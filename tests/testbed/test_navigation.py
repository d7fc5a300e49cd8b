"""Walking to a target on an ideal robot: the walker's commands integrated as a planar body."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.control.navigation import TargetWalker

CFG = config.load()
CRAWL = CFG.gait.speed * CFG.gait.target_tolerance / (2 * CFG.gait.max_step_length)


def walk(target, pose=(0.0, 0.0, 0.0), dt=0.01, duration=60.0):
    """Follow the walker's commands with a body that moves exactly as commanded; returns the final
    pose and the time at which the walker arrived."""
    walker = TargetWalker(CFG.gait, target)
    x, y, yaw = pose
    for k in range(int(duration / dt)):
        twist = walker.command((x, y, yaw))
        if walker.arrived:
            return (x, y, yaw), k * dt
        x += (twist.vx * np.cos(yaw) - twist.vy * np.sin(yaw)) * dt
        y += (twist.vx * np.sin(yaw) + twist.vy * np.cos(yaw)) * dt
        yaw += twist.wz * dt
    return (x, y, yaw), None


def test_target_walker_turns_towards_the_target_and_walks():
    walker = TargetWalker(CFG.gait, (0.0, 1.0))
    command = walker.command((0.0, 0.0, 0.0))          # target to the left: turn left, barely walk
    assert command.wz > 0 and command.vx < 0.01
    command = walker.command((0.0, 0.0, np.pi / 2))    # facing it: walk straight
    assert command.vx == pytest.approx(CFG.gait.speed) and command.wz == pytest.approx(0.0, abs=1e-12)


def test_target_walker_crawls_through_the_tolerance_and_stops_when_the_target_is_abeam():
    walker = TargetWalker(CFG.gait, (0.0, 1.0))
    inside = walker.command((0.0, 1.0 - 0.5 * CFG.gait.target_tolerance, np.pi / 2))
    assert inside.vx == pytest.approx(CRAWL) and not walker.arrived        # 9.4 mm/s, target still ahead
    assert walker.command((0.0, 1.001, np.pi / 2)).vx == 0.0 and walker.arrived   # passed it: stop
    assert walker.command((0.0, 0.0, np.pi / 2)).vx == 0.0                # and stay stopped


def test_an_ideal_robot_stops_on_the_target_not_at_the_edge_of_the_tolerance():
    (x, y, _), arrival = walk((2.0, 1.5))
    assert arrival is not None and arrival < 35.0
    assert np.hypot(x - 2.0, y - 1.5) < 0.2 * CFG.gait.target_tolerance      # 3 mm, not 15 mm


def test_within_the_last_stride_the_walker_steps_sideways_to_the_target_without_turning():
    walker = TargetWalker(CFG.gait, (4.0, 0.0))
    command = walker.command((3.97, -0.02, 0.0))        # 3.6 cm off, to the front left
    assert command.wz == 0.0 and command.vx > 0.0 and command.vy > 0.0
    assert command.vy / command.vx == pytest.approx(0.02 / 0.03)
    (x, y, yaw), arrival = walk((4.0, 0.0), pose=(3.95, -0.03, 0.3))
    assert arrival is not None and np.hypot(x - 4.0, y) < 0.1 * CFG.gait.target_tolerance
    assert yaw == 0.3                                   # it never turned


def test_a_walk_that_ends_at_arrival_ends_its_settle_time_after_the_robot_stopped_on_the_target():
    from testbed.runtime.runner import ARRIVAL_SETTLE, run
    walk_to = {"run": {"gait": "tripod", "duration": 16.0}, "gait": {"target": [0.3, 0.0]}}
    whole = run(config.load(overrides=walk_to)).metrics
    ending = run(config.load(overrides={**walk_to, "gait": {"target": [0.3, 0.0], "end_at_arrival": True}}))
    arrived = ending.metrics["arrival_time_s"]
    assert 5.0 < arrived < 16.0 - ARRIVAL_SETTLE
    assert whole["arrival_time_s"] == arrived and whole["sim_time_s"] == pytest.approx(16.0)
    assert ending.metrics["sim_time_s"] == pytest.approx(arrived + ARRIVAL_SETTLE, abs=0.011)
    assert "arrived at the target" in ending.note
    assert ending.metrics["target_error_m"] == pytest.approx(whole["target_error_m"], abs=0.002)
    assert ending.metrics["target_error_m"] < 0.03
