"""Synthetic run ticks for the dataset tests: an analytic rocking body standing on flat ground,
read by the real sensor suite and fed to a real estimator, as the run loop does, without DART."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.registry import make_estimator
from sensors.suite import SensorSuite
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.world.contact import FootContacts
from testbed.control.command import Command
from testbed.runtime.recording import Tick
from testbed.model.robot import build_urdf
from testbed.world.terrain import FlatTerrain
from testbed.model.truth import Truth

ROCK_HZ = 1.0
ROLL_AMPLITUDE = np.radians(3.0)
PITCH_AMPLITUDE = np.radians(2.0)
HEIGHT = 0.1
FEET_XY = np.array([[0.16, 0.16], [0.0, 0.2], [-0.16, 0.16], [-0.16, -0.16], [0.0, -0.2], [0.16, -0.16]])


def synthetic_config(estimator: str = "complementary", **sections) -> Config:
    """The default config with `estimator` as the run's estimator, other sections overridden."""
    return config_module.load().replace(run={"estimator": estimator}, **sections)


def _attitude(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch and their first two derivatives at t."""
    w = 2 * np.pi * ROCK_HZ
    angles = np.array([ROLL_AMPLITUDE * np.sin(w * t), PITCH_AMPLITUDE * np.sin(0.7 * w * t)])
    rates = np.array([ROLL_AMPLITUDE * w * np.cos(w * t), PITCH_AMPLITUDE * 0.7 * w * np.cos(0.7 * w * t)])
    accelerations = -np.array([w**2, (0.7 * w) ** 2]) * angles
    return angles, rates, accelerations


def truth_at(t: float, contact: np.ndarray) -> Truth:
    (roll, pitch), (roll_rate, pitch_rate), (roll_acc, pitch_acc) = _attitude(t)
    rotation = Rotation.from_euler("ZYX", [0.0, pitch, roll]).as_matrix()
    feet = np.column_stack([FEET_XY, np.full(6, 0.01)])
    feet[~contact, 2] = 0.04
    normal = np.where(contact, 23.0 / max(contact.sum(), 1), 0.0)
    joints = 0.3 * np.sin(2 * np.pi * 0.5 * t + np.arange(18))
    return Truth(
        t=t, body_position=np.array([0.01 * t, 0.0, HEIGHT]), body_rotation=rotation,
        body_linear_velocity=np.array([0.01, 0.0, 0.0]),
        body_angular_velocity=np.array([roll_rate, pitch_rate, 0.0]),
        body_linear_acceleration=np.zeros(3), body_angular_acceleration=np.array([roll_acc, pitch_acc, 0.0]),
        joint_positions=joints, joint_velocities=np.cos(joints), foot_positions=feet,
        foot_forces=np.column_stack([np.zeros((6, 2)), normal]), foot_normal_forces=normal,
        foot_contact=contact.copy(), com_position=np.array([0.01 * t, 0.0, HEIGHT - 0.01]))


def _contact_at(t: float) -> np.ndarray:
    """All feet down except leg 2 lifted for 0.2 s of every second (so contacts change)."""
    contact = np.ones(6, dtype=bool)
    contact[1] = (t % 1.0) < 0.8
    return contact


def generate_ticks(config: Config, seconds: float) -> Iterator[Tick]:
    """The ticks of `seconds` of the synthetic motion at the config's physics step, the first at
    t = 0 (before any step, as the run loop records it)."""
    suite = SensorSuite.from_config(config)
    filter_ = make_estimator(config.run.estimator, config)
    dt = config.run.time_step
    for step in range(int(round(seconds / dt)) + 1):
        t = step * dt
        contact = _contact_at(t)
        truth = truth_at(t, contact)
        samples = suite.update(truth)
        estimates = [e for e in (filter_.update(s) for s in samples) if e is not None]
        stance = truth.foot_positions[contact, :2]
        yield Tick(
            truth=truth, truth_quaternion=Rotation.from_matrix(truth.body_rotation).as_quat(),
            contacts=FootContacts(truth.foot_forces, truth.foot_normal_forces,
                                  np.where(contact[:, None], [0.0, 0.0, 1.0], 0.0), truth.foot_positions - [0, 0, 0.01],
                                  contact.copy()),
            support_polygon=stance, stability_margin=0.05 + 0.01 * np.sin(t),
            samples=samples, estimates=estimates,
            command=Command(t=t, phase=np.full(6, (t % 1.0)), swinging=~contact,
                            foot_targets=np.column_stack([FEET_XY, np.full(6, -HEIGHT)]),
                            joint_targets=truth.joint_positions + 0.01, body_twist=np.array([0.01, 0.0, 0.0])))


def terrain_and_urdf(config: Config) -> tuple[FlatTerrain, str]:
    return FlatTerrain(config.terrain), build_urdf(config.robot)
