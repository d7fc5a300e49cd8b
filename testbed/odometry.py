"""The robot's own planar pose, for walking straight and to targets without ground truth.

Leg odometry: feet in stance stay where they are on the ground, so between two encoder samples
the body moved by the rigid planar motion that carries the stance feet's new body-frame positions
onto their old ones (the least-squares, Kabsch, alignment of the two point sets).
Heading: feet twist on the ground a little at every step, which leg odometry cannot see, so the
heading comes from the gyro, whose bias is calibrated while the robot stands still at start-up.
The leg displacements are rotated into the world with that heading.
"""

from __future__ import annotations

import numpy as np
from testbed.kinematics import LegGeometry, foot_positions


class LegOdometry:
    def __init__(self, geometry: LegGeometry):
        self.geometry = geometry
        self.x = 0.0
        self.y = 0.0
        self.yaw = 0.0
        self._feet: np.ndarray | None = None       # the reference reading: feet, stance, heading
        self._stance: np.ndarray | None = None
        self._feet_heading: float | None = None

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.x, self.y, self.yaw

    def update(self, joint_positions: np.ndarray, stance: np.ndarray, heading: float | None = None) -> None:
        """A new encoder reading (18,) rad with the legs known to be on the ground (6,) bool; with
        `heading` (rad, from the gyro) the displacement is rotated by it instead of the legs' yaw."""
        if not np.all(np.isfinite(joint_positions)):
            return   # an encoder dropout: keep the last good reading as the reference
        feet = foot_positions(self.geometry, joint_positions)
        if self._feet is not None:
            both = stance & self._stance
            if both.sum() >= 2:
                self._integrate(self._feet[both], feet[both], self._feet_heading, heading)
        self._feet, self._stance, self._feet_heading = feet, stance.copy(), heading

    def _integrate(self, before: np.ndarray, after: np.ndarray, heading_before: float | None,
                   heading_after: float | None) -> None:
        # The body motion (R(turn), shift) satisfies before = R @ after + shift for feet fixed on the
        # ground: the planar Kabsch solution, whose angle is atan2 of the summed cross and dot
        # products of the centred points. (scipy's 3-D align_vectors leaves the rotation about the
        # axis of two feet undetermined, so the planar problem is solved here directly.)
        centre_before, centre_after = before[:, :2].mean(axis=0), after[:, :2].mean(axis=0)
        b, a = before[:, :2] - centre_before, after[:, :2] - centre_after
        turn = float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
        c, s = np.cos(turn), np.sin(turn)
        shift = centre_before - np.array([c * centre_after[0] - s * centre_after[1], s * centre_after[0] + c * centre_after[1]])
        # The shift is expressed in the body frame of the reference reading: rotate it by that heading.
        previous = self.yaw if heading_before is None else heading_before
        cos_yaw, sin_yaw = np.cos(previous), np.sin(previous)
        self.x += cos_yaw * shift[0] - sin_yaw * shift[1]
        self.y += sin_yaw * shift[0] + cos_yaw * shift[1]
        self.yaw = self.yaw + turn if heading_after is None else heading_after


class GyroHeading:
    """Yaw from the body-frame gyro's z rate, its bias averaged over a still start-up period."""

    def __init__(self, calibration_time: float):
        self.calibration_time = calibration_time
        self.yaw = 0.0
        self.bias = 0.0
        self._sum = 0.0
        self._count = 0
        self._last_t: float | None = None

    def update(self, t: float, yaw_rate: float) -> None:
        if not np.isfinite(yaw_rate):
            return
        if t < self.calibration_time:
            self._sum += yaw_rate
            self._count += 1
            self.bias = self._sum / self._count
        elif self._last_t is not None:
            self.yaw += (yaw_rate - self.bias) * (t - self._last_t)
        self._last_t = t
