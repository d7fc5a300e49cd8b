"""Speed of the notebook API and of the gymnasium environment (`make bench`, `pytest -m bench`):

- a 60 s run's IMU table (60,000 messages) loads in under 0.5 s;
- an env step with the default 10 ms control period costs at most 1.2 times 10 physics steps of
  `testbed run` on the same config (tripod, EKF, the built-in posture pilot, the run recorded to
  MCAP as the command line records it).

The machine may be shared: each figure is the best of a few repetitions, the env and the run
alternating, and the load average is printed beside it.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

import testbed
from datasets.recorder import McapRecorder
from testbed.api import make_config
from testbed.gym_env import HexapodTestbedEnv
from testbed.runtime.runner import run

pytestmark = pytest.mark.bench
TABLE_SECONDS = 0.5
STEP_RATIO = 1.2
REPEATS = 3
CONFIG = {"run": {"terrain": "flat", "gait": "tripod", "estimator": "ekf", "controller": "posture"}}


def best_of(repeats: int, measure) -> float:
    return min(measure() for _ in range(repeats))


def test_imu_table_of_a_60_s_run_loads_in_half_a_second(tmp_path, capsys):
    path = tmp_path / "walk60.mcap"
    testbed.run({"run": {**CONFIG["run"], "duration": 60.0}}, out=path)
    dataset = testbed.load(path)
    rows = len(dataset.table("/sensors/imu"))

    def load_table() -> float:
        started = time.perf_counter()
        testbed.load(path).table("/sensors/imu")
        return time.perf_counter() - started

    seconds = best_of(REPEATS, load_table)
    with capsys.disabled():
        print(f"\nIMU table of a 60 s run: {rows} rows in {seconds:.3f} s (best of {REPEATS}; "
              f"load average {os.getloadavg()[0]:.2f})")
    assert rows == 60_001
    assert seconds < TABLE_SECONDS


def run_seconds_per_step(duration: float, folder) -> float:
    """Wall time per physics step of `testbed run` (its loop: metrics `wall_s`), recorded to MCAP."""
    config = make_config({"run": {**CONFIG["run"], "duration": duration}})
    outcome = run(config, McapRecorder(folder / f"run{time.perf_counter_ns()}.mcap"))
    return outcome.metrics["wall_s"] / outcome.metrics["sim_steps"]


def env_seconds_per_step(env: HexapodTestbedEnv, steps: int, action: np.ndarray | None) -> float:
    env.reset(seed=0)
    started = time.perf_counter()
    for _ in range(steps):
        env.step(action if action is not None else env.sim.standing_targets)
    return (time.perf_counter() - started) / steps


def test_env_step_costs_at_most_10_physics_steps_of_testbed_run_plus_20_percent(tmp_path, capsys):
    duration = 5.0
    posture = HexapodTestbedEnv(config=CONFIG, action="posture")
    joints = HexapodTestbedEnv(config=CONFIG, action="joints")
    steps = int(round(duration / posture.control_period))
    zero = np.zeros(3, dtype=np.float32)
    run_step, posture_step, joints_step = [], [], []
    for _ in range(REPEATS):        # interleaved: the load of a shared machine shifts
        run_step.append(run_seconds_per_step(duration, tmp_path) * posture.physics_steps)
        posture_step.append(env_seconds_per_step(posture, steps, zero))
        joints_step.append(env_seconds_per_step(joints, steps, None))
    ratio, joints_ratio = min(posture_step) / min(run_step), min(joints_step) / min(run_step)
    with capsys.disabled():
        print(f"\n10 physics steps of testbed run: {min(run_step) * 1e3:.3f} ms; env step (10 ms, action posture): "
              f"{min(posture_step) * 1e3:.3f} ms, ratio {ratio:.3f}; action joints: {min(joints_step) * 1e3:.3f} ms, "
              f"ratio {joints_ratio:.3f} (best of {REPEATS}, {duration:g} s each; load average {os.getloadavg()[0]:.2f})")
    assert ratio <= STEP_RATIO
