"""The whole tick (simulation, sensors, pilot) on real runs: a still accelerometer reads gravity,
the same seed gives the same run, and the recorder sees every tick."""

import numpy as np
import pytest

from sensors.samples import ImuSample
from testbed.runtime import config
from testbed.runtime.runner import run
from tests.recorders import Collect


def test_still_accelerometer_reads_gravity_in_the_body_frame():
    """Standing on flat ground (no calibration poses), an IMU without systematic errors averages R^T (0, 0, g)."""
    perfect = {"turn_on_bias": 0.0, "scale_factor": 0.0, "misalignment": 0.0, "bias_instability": 0.0}
    cfg = config.load(overrides={"run": {"duration": 2.0}, "gait": {"calibration_tilt_deg": 0.0},
                                 "sensors": {"imu": {"accel": perfect, "gyro": perfect}}})
    collect = Collect()
    run(cfg, collect)
    still = [t for t in collect.ticks if t.truth.t > 1.0]
    accel = np.array([s.accel for t in still for s in t.samples if isinstance(s, ImuSample)])
    expected = np.mean([t.truth.body_rotation.T @ [0.0, 0.0, cfg.run.gravity] for t in still], axis=0)
    sigma = cfg.sensors.imu.accel.noise_density * np.sqrt(cfg.sensors.imu.rate) / np.sqrt(len(accel))
    assert len(accel) == pytest.approx(1000, abs=1)
    assert np.all(np.abs(accel.mean(axis=0) - expected) < 3 * sigma)   # 3 sigma of the mean
    assert np.linalg.norm(expected) == pytest.approx(cfg.run.gravity, rel=1e-4)


def test_same_seed_same_walk_and_a_different_seed_differs():
    cfg = config.load(overrides={"run": {"terrain": "rough", "gait": "tripod", "duration": 1.5, "seed": 4}})
    first, second, other = Collect(), Collect(), Collect()
    run(cfg, first)
    run(cfg, second)
    run(cfg.replace(run={"seed": 5}), other)
    positions = lambda c: np.array([t.truth.body_position for t in c.ticks])
    imu = lambda c: np.array([s.accel for t in c.ticks for s in t.samples if isinstance(s, ImuSample)])
    assert np.array_equal(positions(first), positions(second))
    assert np.array_equal(imu(first), imu(second))
    assert not np.array_equal(positions(first), positions(other))
    assert first.finished[0]["sim_steps"] == 1500 and first.finished[1] is None
