"""The robot's onboard software: everything downstream of the sensors, nothing that reads truth.

Per tick: sensor samples -> estimator and leg odometry -> body twist (fixed, or walking to a
target) -> gait generator (foot targets in the body frame) -> inverse kinematics -> joint targets.
"""

from __future__ import annotations

import numpy as np

from sensors.samples import EncoderSample, FootSample, ImuSample, Sample
from testbed.config import Config
from testbed.gait import GaitGenerator, Twist
from testbed.kinematics import LegGeometry, UnreachableTarget, inverse_kinematics
from testbed.navigation import TargetWalker
from testbed.odometry import GyroHeading, LegOdometry
from testbed.recording import Command


def make_estimator_or_none(name: str, config: Config):
    if name == "none":
        return None
    from estimators.registry import make_estimator
    return make_estimator(name, config)


class Pilot:
    def __init__(self, config: Config, geometry: LegGeometry, start_feet: np.ndarray, start_joints: np.ndarray):
        self.config = config
        self.geometry = geometry
        self.dt = config.run.time_step
        # The gait keeps the stance the robot started in (known from its own joint angles): on a
        # slope that is the stance of a level body on that slope.
        self.gait = GaitGenerator(config.run.gait, start_feet, config.gait.period(config.run.gait),
                                  config.gait.swing_height)
        self.joint_targets = np.array(start_joints, dtype=float)
        self.estimator = make_estimator_or_none(config.run.estimator, config)
        self.odometry = LegOdometry(geometry)
        self.heading = GyroHeading(config.gait.still_time)
        self.heading_reference = 0.0
        self.imu_to_body_z = np.array(config.sensors.imu.body_from_sensor)[2]   # z row of body_from_imu
        self.walker = TargetWalker(config.gait, tuple(config.gait.target)) if config.gait.target else None
        self.foot_contact = np.ones(6, dtype=bool)
        self.ik_limited_ticks = 0

    def tick(self, t: float, samples: list[Sample]) -> tuple[Command, list]:
        estimates = self._absorb(samples)
        twist = self._twist(t)
        if self._walking(t):
            feet = self.gait.step(t - self.config.gait.still_time, self.dt, twist)
        else:
            feet = self.gait.state.feet.copy()
        self._solve_ik(feet)
        command = Command(t=t, phase=self.gait.phase(t), swinging=self.gait.state.swinging.copy(),
                          foot_targets=feet, joint_targets=self.joint_targets.copy(),
                          body_twist=np.array([twist.vx, twist.vy, twist.wz]))
        return command, estimates

    def _absorb(self, samples: list[Sample]) -> list:
        estimates = []
        for sample in samples:
            if self.estimator is not None:
                estimate = self.estimator.update(sample)
                if estimate is not None:
                    estimates.append(estimate)
            if isinstance(sample, ImuSample):
                self.heading.update(sample.t, float(self.imu_to_body_z @ sample.gyro))
            elif isinstance(sample, FootSample):
                self.foot_contact = np.asarray(sample.contact, dtype=bool)
            elif isinstance(sample, EncoderSample):
                stance = self.foot_contact & ~self.gait.state.swinging
                self.odometry.update(np.asarray(sample.positions), stance, self.heading.yaw)
        return estimates

    def _walking(self, t: float) -> bool:
        """Walking gaits start once the gyro bias is calibrated on the still robot."""
        return self.config.run.gait != "stand" and t >= self.config.gait.still_time

    def _twist(self, t: float) -> Twist:
        if not self._walking(t):
            return Twist()
        gait = self.config.gait
        ramp = min(1.0, (t - gait.still_time) / gait.start_ramp) if gait.start_ramp > 0 else 1.0
        if self.walker is not None:
            command = self.walker.command(self.odometry.pose)
            if self.walker.arrived:
                self.gait.stop()
            return Twist(command.vx * ramp, command.vy * ramp, command.wz * ramp)
        # Hold the commanded heading against the feet's twisting on the ground.
        self.heading_reference += gait.turn_rate * ramp * self.dt
        error = np.arctan2(np.sin(self.heading_reference - self.heading.yaw), np.cos(self.heading_reference - self.heading.yaw))
        correction = float(np.clip(gait.heading_gain * error, -gait.cruise_turn_rate, gait.cruise_turn_rate))
        return Twist(gait.speed * ramp, gait.lateral_speed * ramp, gait.turn_rate * ramp + correction)

    def _solve_ik(self, feet: np.ndarray) -> None:
        """Joint targets for the foot targets; a leg whose target is out of reach keeps its last
        joint targets (the body gives way rather than the leg overreaching), and the tick counts."""
        limited = False
        for leg in range(6):
            try:
                self.joint_targets[3 * leg:3 * leg + 3] = inverse_kinematics(self.geometry, leg, feet[leg])
            except UnreachableTarget:
                limited = True
        self.ik_limited_ticks += limited
