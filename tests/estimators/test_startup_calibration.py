"""The fusion filters learn the accelerometer offset from the start-up poses (testbed/startup.py,
estimators/stillness.py), in the physics: an offset reads exactly as a tilt until the body turns."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensors.suite import SensorSuite
from testbed import config as config_module
from testbed.kinematics import foot_positions
from testbed.pilot import Pilot
from testbed.runner import build_simulation, true_roll_pitch

OFFSET_STD = 0.098      # m/s^2: 10 mg per axis, five times the default IMU's calibrated residual


def stand_and_measure(estimator: str, tilt_deg: float, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Stand through the start-up and 0.3 s more; (roll, pitch) error at the end, rad, and the
    accelerometer's true turn-on offset, m/s^2."""
    config = config_module.load().replace(
        run={"gait": "stand", "seed": seed, "estimator": estimator, "duration": 3.0},
        gait={"calibration_tilt_deg": tilt_deg}, sensors={"imu": {"accel": {"turn_on_bias": OFFSET_STD}}},
        estimators={"ekf": {"accel_bias_initial_std": OFFSET_STD}})     # the filter's belief matches the part
    sim = build_simulation(config)
    sensors = SensorSuite.from_config(config)
    pilot = Pilot(config, sim.geometry, foot_positions(sim.geometry, sim.standing_targets), sim.standing_targets)
    truth = sim.truth()
    command, _ = pilot.tick(sim.time, sensors.update(truth))
    for _ in range(int(round((config.gait.startup_time + 0.3) / config.run.time_step))):
        sim.step(command.joint_targets)
        truth = sim.truth()
        command, _ = pilot.tick(sim.time, sensors.update(truth))
    estimate = pilot.latest_estimate
    error = np.subtract((estimate.roll, estimate.pitch), true_roll_pitch(truth))
    return error, sensors.imu.channels.triads[0].turn_on_bias


@pytest.mark.parametrize("estimator", ["ekf", "ukf"])
def test_offset_learned_from_the_poses(estimator):
    error, offset = stand_and_measure(estimator, tilt_deg=12.0)
    apparent = np.degrees(np.abs(offset[:2]) / 9.81)      # the tilt error the offset alone would cause
    assert apparent.max() > 1.5                           # seed 7: 30 mg on y
    assert np.degrees(np.abs(error)).max() < 0.1, (np.degrees(error), apparent)


def test_without_poses_the_offset_stays_a_tilt():
    error, offset = stand_and_measure("ekf", tilt_deg=0.0)
    # Roll from the y offset, pitch from the x offset: within 10 % of what the offset alone does.
    np.testing.assert_allclose(np.abs(error), np.abs(offset[[1, 0]]) / 9.81, rtol=0.1)
