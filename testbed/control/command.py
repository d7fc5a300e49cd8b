"""What the built-in pilot commanded at one tick, recorded beside the joint targets."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

class Command(NamedTuple):
    """What the controller and gait commanded at one tick (a named tuple: one is built per physics step)."""
    t: float
    phase: np.ndarray            # (6,) gait phase of each leg in [0, 1)
    swinging: np.ndarray         # (6,) bool
    foot_targets: np.ndarray     # (6, 3) m, body frame, after the posture controller
    joint_targets: np.ndarray    # (18,) rad, after inverse kinematics
    body_twist: np.ndarray       # (3,) commanded vx, vy (m/s), wz (rad/s) in the body frame
