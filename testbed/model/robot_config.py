"""The robot's parameters (the `[robot]` config section): sizes, masses, joint limits, servos, stance."""

from __future__ import annotations

import math
from dataclasses import dataclass

from testbed.model.validation import finite, positive, require

@dataclass(frozen=True)
class RobotConfig:
    body_mass: float
    body_size: tuple[float, ...]
    leg_base_angle_deg: tuple[float, ...]
    leg_base_distance: tuple[float, ...]
    coxa_mass: float
    coxa_size: tuple[float, ...]
    femur_length: float
    femur_mass: float
    femur_section: tuple[float, ...]
    tibia_length: float
    tibia_mass: float
    tibia_radius: float
    foot_radius: float
    joint_lower_deg: tuple[float, ...]
    joint_upper_deg: tuple[float, ...]
    servo_torque_limit: float
    servo_speed_limit: float
    servo_gain: float
    stance_radius: float
    stance_height: float

    def __post_init__(self) -> None:
        require(len(self.body_size) == 3, "robot.body_size needs 3 numbers")
        require(len(self.coxa_size) == 3, "robot.coxa_size needs 3 numbers")
        require(len(self.femur_section) == 2, "robot.femur_section needs 2 numbers")
        require(len(self.leg_base_angle_deg) == 6, "robot.leg_base_angle_deg needs 6 numbers (one per leg)")
        require(len(self.leg_base_distance) == 6, "robot.leg_base_distance needs 6 numbers (one per leg)")
        require(len(self.joint_lower_deg) == 3 and len(self.joint_upper_deg) == 3,
                 "robot.joint_lower_deg and joint_upper_deg need 3 numbers (coxa, femur, tibia)")
        positive("robot sizes and masses", self.body_mass, *self.body_size, self.coxa_mass, *self.coxa_size,
                         self.femur_length, self.femur_mass, *self.femur_section, self.tibia_length,
                         self.tibia_mass, self.tibia_radius, self.foot_radius, *self.leg_base_distance)
        positive("robot servo limits", self.servo_torque_limit, self.servo_speed_limit, self.servo_gain)
        positive("robot stance", self.stance_radius, self.stance_height)
        finite("robot.leg_base_angle_deg", *self.leg_base_angle_deg)
        for lower, upper in zip(self.joint_lower_deg, self.joint_upper_deg):
            require(math.isfinite(lower) and math.isfinite(upper) and -180 <= lower < upper <= 180,
                     f"robot joint limits must satisfy -180 <= lower < upper <= 180, got [{lower}, {upper}]")
        require(self.stance_height > self.foot_radius,
                 "robot.stance_height must exceed robot.foot_radius")
