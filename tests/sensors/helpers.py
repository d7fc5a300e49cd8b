"""Hand-built ground truth and sensor configs for the sensor tests."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sensors.config import SensorsConfig
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from sensors.still import still_truth
from sensors.suite import SensorSuite
from testbed.runtime import config as testbed_config
from testbed.model.truth import NUM_JOINTS, NUM_LEGS, Truth

GRAVITY = 9.81
IDEAL_AXES = {"turn_on_bias": 0.0, "scale_factor": 0.0, "misalignment": 0.0, "bias_instability": 0.0,
              "rate_random_walk": 0.0}


def truth(t: float = 0.0, rotation: np.ndarray | None = None, angular_velocity=(0.0, 0.0, 0.0),
          angular_acceleration=(0.0, 0.0, 0.0), linear_acceleration=(0.0, 0.0, 0.0),
          joint_positions: np.ndarray | None = None, foot_forces: np.ndarray | None = None) -> Truth:
    """A still body (sensors.still) with the given motion, joint angles and foot forces."""
    forces = np.full(NUM_LEGS, 4.0) if foot_forces is None else np.asarray(foot_forces, dtype=float)
    return still_truth(t, rotation)._replace(
        body_angular_velocity=np.asarray(angular_velocity, dtype=float),
        body_angular_acceleration=np.asarray(angular_acceleration, dtype=float),
        body_linear_acceleration=np.asarray(linear_acceleration, dtype=float),
        joint_positions=np.zeros(NUM_JOINTS) if joint_positions is None else np.asarray(joint_positions, dtype=float),
        foot_normal_forces=forces, foot_contact=forces > 0)


def pitched(degrees: float) -> np.ndarray:
    return Rotation.from_euler("y", degrees, degrees=True).as_matrix()


def sensors_config(**sections) -> SensorsConfig:
    """The default sensors config with some keys changed: sensors_config(imu={"rate": 400.0})."""
    return testbed_config.load(overrides={"sensors": sections}).sensors


def ideal_imu(noise: bool = True, **imu) -> dict:
    """An IMU override without systematic errors or drift; white noise kept unless noise=False."""
    axes = dict(IDEAL_AXES, **({} if noise else {"noise_density": 0.0}))
    return {"accel": dict(axes), "gyro": dict(axes), **imu}


def run(config: SensorsConfig, truths, seed: int = 0) -> list[Sample]:
    suite = SensorSuite.from_sections(config, GRAVITY, seed)
    return [sample for state in truths for sample in suite.update(state)]


def steps(seconds: float, make=truth, step: float = 0.001):
    """Truths at t = 0, step, 2 step, ... seconds, built by make(t)."""
    return [make(k * step) for k in range(int(round(seconds / step)) + 1)]


def of_type(samples, kind):
    return [sample for sample in samples if isinstance(sample, kind)]


def flatten(samples) -> dict[tuple[str, int, float], np.ndarray]:
    """Every sample as {(stream, member, t): values}; the IMU's values are accel then gyro."""
    flat = {}
    for s in samples:
        if isinstance(s, ImuSample):
            flat[("imu", 0, s.t)] = np.concatenate((s.accel, s.gyro))
        elif isinstance(s, AccelSample):
            flat[("accel_array", s.index, s.t)] = s.accel
        elif isinstance(s, EncoderSample):
            flat[("encoder", 0, s.t)] = s.positions
        elif isinstance(s, FootSample):
            flat[("foot", 0, s.t)] = s.normal_forces
    return flat
