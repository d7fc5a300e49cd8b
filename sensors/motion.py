"""Body-frame motion that inertial sensors on the body measure, from one ground-truth snapshot.

For a point r fixed on the body (rigid-body kinematics, world frame):
    a_p = a_O + alpha x r + omega x (omega x r)
and the specific force an accelerometer there measures is f = a_p - g_vec, g_vec = (0, 0, -g).
Everything is expressed in the body frame (rotations preserve cross products), so a point costs
one matrix-vector product with the lever-arm matrix [alpha]x + [omega]x^2.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from testbed.model.truth import Truth


class BodyMotion:
    """Specific force at the body origin, angular velocity and lever-arm matrix, all in the body frame."""

    __slots__ = ("specific_force", "angular_velocity", "lever_arm")

    def __init__(self, truth: Truth, gravity: float) -> None:
        self.specific_force, self.angular_velocity, self.lever_arm = body_motion_arrays(
            truth.body_rotation, truth.body_linear_acceleration, truth.body_angular_velocity,
            truth.body_angular_acceleration, gravity)

    def specific_force_at(self, points: np.ndarray) -> np.ndarray:
        """Specific force (m/s^2, body frame) at body-frame point(s) `points`, shape (3,) or (N, 3)."""
        return self.specific_force + points @ self.lever_arm.T


# Compiled: the IMU asks for this at 1 kHz, and numpy's per-call cost on 3-vectors dominates.
@njit(cache=True)
def body_motion_arrays(rotation, acceleration, angular_velocity, angular_acceleration, gravity):
    """Body-frame specific force at the origin R^T (a - g_vec), angular velocity omega_b = R^T omega
    and the lever-arm matrix L = [alpha_b]x + omega_b omega_b^T - |omega_b|^2 I (alpha_b = R^T alpha),
    with L r = alpha_b x r + omega_b x (omega_b x r)."""
    force, omega, alpha = np.empty(3), np.empty(3), np.empty(3)
    for i in range(3):
        force[i] = (rotation[0, i] * acceleration[0] + rotation[1, i] * acceleration[1]
                    + rotation[2, i] * (acceleration[2] + gravity))
        omega[i] = (rotation[0, i] * angular_velocity[0] + rotation[1, i] * angular_velocity[1]
                    + rotation[2, i] * angular_velocity[2])
        alpha[i] = (rotation[0, i] * angular_acceleration[0] + rotation[1, i] * angular_acceleration[1]
                    + rotation[2, i] * angular_acceleration[2])
    wx, wy, wz = omega[0], omega[1], omega[2]
    ax, ay, az = alpha[0], alpha[1], alpha[2]
    lever = np.empty((3, 3))
    lever[0, 0], lever[0, 1], lever[0, 2] = -(wy * wy + wz * wz), wx * wy - az, wx * wz + ay
    lever[1, 0], lever[1, 1], lever[1, 2] = wx * wy + az, -(wx * wx + wz * wz), wy * wz - ax
    lever[2, 0], lever[2, 1], lever[2, 2] = wx * wz - ay, wy * wz + ax, -(wx * wx + wy * wy)
    return force, omega, lever


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
