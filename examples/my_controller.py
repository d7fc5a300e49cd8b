"""A user's controller: the robot stands on its six feet and sways its body in a slow circle.

    PYTHONPATH=examples testbed run --controller my_controller:BodySway --estimator ekf --duration 10

A controller sees only what the robot's computer has: the sensor samples of the tick and the
estimator's latest estimate. It answers 18 joint position targets (rad), here from the feet it
wants in the body frame through the robot's inverse kinematics.
"""

import math

import numpy as np

from testbed import Controller
from testbed.model.kinematics import LegGeometry, foot_positions, joint_targets_or_last

SWAY_RADIUS = 0.015     # m
SWAY_PERIOD = 4.0       # s per circle
LEVELLING_GAIN = 0.5    # share of the estimated tilt taken out of the feet's heights


class BodySway(Controller):
    def __init__(self, geometry: LegGeometry):
        self.geometry = geometry
        self.stance = None          # the feet, body frame, in the start pose
        self.targets = None

    @classmethod
    def from_config(cls, config) -> "BodySway":
        return cls(LegGeometry.from_config(config.robot))

    def start(self, joint_positions):
        self.targets = np.array(joint_positions, dtype=float)
        self.stance = foot_positions(self.geometry, self.targets)

    def tick(self, t, samples, estimate):
        phase = 2 * math.pi * t / SWAY_PERIOD
        # moving the feet one way moves the body the other way over them
        feet = self.stance - SWAY_RADIUS * np.array([math.cos(phase) - 1.0, math.sin(phase), 0.0])
        if estimate is not None:
            # lower the feet on the side the body leans to: z_i -= gain * (roll * y_i - pitch * x_i)
            feet[:, 2] -= LEVELLING_GAIN * (estimate.roll * feet[:, 1] - estimate.pitch * feet[:, 0])
        self.targets, _ = joint_targets_or_last(self.geometry, feet, self.targets)
        return self.targets
