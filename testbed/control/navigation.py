"""Walk to a target: turn towards it, walk, slow down near it, stop on it.

It steers on the robot's own pose (never ground truth): a full-state estimator's, else the leg
odometry's. The speed falls in proportion to the
distance over the last two strides, down to a crawl at the tolerance. Within the last stride
(`max_step_length`) it no longer turns: it walks straight at the target in the body frame
(forwards and sideways), since turning towards a target a few centimetres off to the side spun
the robot in place. Inside the tolerance it keeps crawling until the target is abeam or behind
the direction it walked last, so that it stops at the point nearest the target, not at the near
edge of the tolerance disc (which left every run a tolerance short along its path). Stopping
costs no overshoot: the stance feet stop with the command and the body with them.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.control.config import GaitConfig
from testbed.control.gait import Twist


class TargetWalker:
    def __init__(self, config: GaitConfig, target: tuple[float, float]):
        self.config = config
        self.target = np.asarray(target, dtype=float)
        self.arrived = False
        self.direction = (1.0, 0.0)     # the body-frame direction it walked last (straight ahead at first)

    def command(self, pose: tuple[float, float, float]) -> Twist:
        if self.arrived:
            return Twist()
        x, y, yaw = pose
        target_x, target_y = self.target.tolist()
        offset_x, offset_y = target_x - x, target_y - y
        distance = math.hypot(offset_x, offset_y)
        bearing = math.atan2(offset_y, offset_x)
        heading_error = math.atan2(math.sin(bearing - yaw), math.cos(bearing - yaw))
        ahead, left = math.cos(heading_error), math.sin(heading_error)      # the target's direction, body frame
        if distance < self.config.target_tolerance and ahead * self.direction[0] + left * self.direction[1] <= 0.0:
            self.arrived = True
            return Twist()
        approach = min(1.0, max(distance, self.config.target_tolerance) / (2.0 * self.config.max_step_length))
        if distance < self.config.max_step_length:
            self.direction = (ahead, left)
            speed = self.config.speed * approach
            return Twist(vx=speed * ahead, vy=speed * left)
        turn = min(max(self.config.heading_gain * heading_error, -self.config.cruise_turn_rate),
                   self.config.cruise_turn_rate)
        # Walk only roughly towards the target.
        alignment = max(0.0, ahead) ** 2
        return Twist(vx=self.config.speed * alignment * approach, wz=turn)
