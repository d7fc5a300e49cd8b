"""Walk to a target: turn towards it, walk, slow down near it, stop within the tolerance.

It steers on the leg-odometry pose (never ground truth).
"""

from __future__ import annotations

import numpy as np

from testbed.config import GaitConfig
from testbed.gait import Twist


class TargetWalker:
    def __init__(self, config: GaitConfig, target: tuple[float, float]):
        self.config = config
        self.target = np.asarray(target, dtype=float)
        self.arrived = False

    def command(self, pose: tuple[float, float, float]) -> Twist:
        if self.arrived:
            return Twist()
        x, y, yaw = pose
        offset = self.target - (x, y)
        distance = float(np.hypot(*offset))
        if distance < self.config.target_tolerance:
            self.arrived = True
            return Twist()
        heading_error = np.arctan2(np.sin(np.arctan2(offset[1], offset[0]) - yaw),
                                   np.cos(np.arctan2(offset[1], offset[0]) - yaw))
        turn = float(np.clip(self.config.heading_gain * heading_error,
                             -self.config.cruise_turn_rate, self.config.cruise_turn_rate))
        # Walk only roughly towards the target; slow down over the last stride so as not to overshoot.
        alignment = max(0.0, np.cos(heading_error)) ** 2
        approach = min(1.0, distance / (2.0 * self.config.max_step_length))
        return Twist(vx=self.config.speed * alignment * approach, wz=turn)
