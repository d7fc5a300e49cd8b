"""Body-frame motion that inertial sensors on the body measure, from one ground-truth snapshot.

For a point r fixed on the body (rigid-body kinematics, world frame):
    a_p = a_O + alpha x r + omega x (omega x r)
and the specific force an accelerometer there measures is f = a_p - g_vec, g_vec = (0, 0, -g).
Everything is expressed in the body frame (rotations preserve cross products), so a point costs
one matrix-vector product with the lever-arm matrix [alpha]x + [omega]x^2.
"""

from __future__ import annotations

import numpy as np

from testbed.truth import Truth


def lever_arm_matrix(omega: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """L with L r = alpha x r + omega x (omega x r) = ([alpha]x + omega omega^T - |omega|^2 I) r."""
    wx, wy, wz = omega.tolist()
    ax, ay, az = alpha.tolist()
    return np.array([[-(wy * wy + wz * wz), wx * wy - az, wx * wz + ay],
                     [wx * wy + az, -(wx * wx + wz * wz), wy * wz - ax],
                     [wx * wz - ay, wy * wz + ax, -(wx * wx + wy * wy)]])


class BodyMotion:
    """Specific force at the body origin, angular velocity and lever-arm matrix, all in the body frame."""

    __slots__ = ("specific_force", "angular_velocity", "lever_arm")

    def __init__(self, truth: Truth, gravity: float) -> None:
        body_from_world = truth.body_rotation.T
        acceleration = truth.body_linear_acceleration
        self.specific_force = body_from_world @ np.array([acceleration[0], acceleration[1], acceleration[2] + gravity])
        self.angular_velocity = body_from_world @ truth.body_angular_velocity
        self.lever_arm = lever_arm_matrix(self.angular_velocity, body_from_world @ truth.body_angular_acceleration)

    def specific_force_at(self, points: np.ndarray) -> np.ndarray:
        """Specific force (m/s^2, body frame) at body-frame point(s) `points`, shape (3,) or (N, 3)."""
        return self.specific_force + points @ self.lever_arm.T


class MotionCache:
    """BodyMotion of the latest truth asked for: the IMU and the accelerometer array share it."""

    def __init__(self, gravity: float) -> None:
        self.gravity = gravity
        self._truth: Truth | None = None
        self._motion: BodyMotion | None = None

    def __call__(self, truth: Truth) -> BodyMotion:
        if truth is not self._truth:
            self._motion = BodyMotion(truth, self.gravity)
            self._truth = truth
        return self._motion
