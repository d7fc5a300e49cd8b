"""Leg kinematics of the paper's hexapod: forward kinematics exactly as eq. 2, closed-form inverse
kinematics of the anthropomorphic leg (Sciavicco-Siciliano, the paper's reference [8]), and the
foot Jacobian. Everything is in the body frame O_b x_b y_b z_b; joint vectors are leg-major
(leg 1: theta_11, theta_21, theta_31; leg 2: ...), as eq. 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from testbed.config import RobotConfig

Elbow = Literal["up", "down"]


class UnreachableTarget(ValueError):
    """A foot target that the leg cannot reach, or only outside its joint limits."""

    def __init__(self, leg: int, target: np.ndarray, reason: str):
        super().__init__(f"leg {leg + 1}: target {np.round(target, 4).tolist()} unreachable: {reason}")
        self.leg = leg
        self.target = target
        self.reason = reason


@dataclass(frozen=True)
class LegGeometry:
    base_angle: np.ndarray       # (6,) rad, theta0_i
    base_distance: np.ndarray    # (6,) m, a01_i
    femur: float                 # a2, m
    tibia: float                 # a3, m
    lower: np.ndarray            # (3,) rad, joint lower limits (coxa, femur, tibia)
    upper: np.ndarray            # (3,) rad

    @classmethod
    def from_config(cls, robot: RobotConfig) -> "LegGeometry":
        return cls(
            base_angle=np.radians(robot.leg_base_angle_deg),
            base_distance=np.asarray(robot.leg_base_distance, dtype=float),
            femur=robot.femur_length,
            tibia=robot.tibia_length,
            lower=np.radians(robot.joint_lower_deg),
            upper=np.radians(robot.joint_upper_deg),
        )

    @property
    def base_positions(self) -> np.ndarray:
        """(6, 3) leg base origins O_0i in the body frame."""
        return np.column_stack([self.base_distance * np.cos(self.base_angle),
                                self.base_distance * np.sin(self.base_angle),
                                np.zeros(6)])


def base_transform(geom: LegGeometry, leg: int) -> np.ndarray:
    """T_0i^b of eq. 2: rotation theta0_i about z_b, translation a01_i along x_0i."""
    c, s = np.cos(geom.base_angle[leg]), np.sin(geom.base_angle[leg])
    a = geom.base_distance[leg]
    return np.array([[c, -s, 0.0, a * c], [s, c, 0.0, a * s], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def leg_transform(geom: LegGeometry, leg: int, q: np.ndarray) -> np.ndarray:
    """T_3i^b of eq. 2: the foot frame O_3i in the body frame for joint angles q = (th1, th2, th3)."""
    th1, th2, th3 = q
    c1, s1 = np.cos(th1), np.sin(th1)
    c2, s2 = np.cos(th2), np.sin(th2)
    c23, s23 = np.cos(th2 + th3), np.sin(th2 + th3)
    reach = geom.femur * c2 + geom.tibia * c23
    t30 = np.array([
        [c1 * c23, -c1 * s23, s1, c1 * reach],
        [s1 * c23, -s1 * s23, -c1, s1 * reach],
        [s23, c23, 0.0, geom.femur * s2 + geom.tibia * s23],
        [0.0, 0.0, 0.0, 1.0],
    ])
    return base_transform(geom, leg) @ t30


def foot_positions(geom: LegGeometry, q: np.ndarray) -> np.ndarray:
    """(6, 3) foot positions p_i^b for the 18 joint angles q: eq. 2 for all legs at once."""
    q = np.asarray(q, dtype=float).reshape(6, 3)
    th1, th2, th3 = q[:, 0], q[:, 1], q[:, 2]
    reach = geom.femur * np.cos(th2) + geom.tibia * np.cos(th2 + th3)
    height = geom.femur * np.sin(th2) + geom.tibia * np.sin(th2 + th3)
    angle = geom.base_angle + th1
    return np.column_stack([
        geom.base_distance * np.cos(geom.base_angle) + reach * np.cos(angle),
        geom.base_distance * np.sin(geom.base_angle) + reach * np.sin(angle),
        height,
    ])


def foot_jacobian(geom: LegGeometry, leg: int, q: np.ndarray) -> np.ndarray:
    """3x3 Jacobian d p_i^b / d (th1, th2, th3) of one leg."""
    th1, th2, th3 = q
    a2, a3 = geom.femur, geom.tibia
    reach = a2 * np.cos(th2) + a3 * np.cos(th2 + th3)
    d_reach = np.array([-a2 * np.sin(th2) - a3 * np.sin(th2 + th3), -a3 * np.sin(th2 + th3)])
    d_height = np.array([a2 * np.cos(th2) + a3 * np.cos(th2 + th3), a3 * np.cos(th2 + th3)])
    angle = geom.base_angle[leg] + th1
    ca, sa = np.cos(angle), np.sin(angle)
    return np.array([
        [-reach * sa, d_reach[0] * ca, d_reach[1] * ca],
        [reach * ca, d_reach[0] * sa, d_reach[1] * sa],
        [0.0, d_height[0], d_height[1]],
    ])


def inverse_kinematics(geom: LegGeometry, leg: int, target: np.ndarray, elbow: Elbow = "up") -> np.ndarray:
    """Joint angles (th1, th2, th3) that put foot `leg` at `target` (body frame).

    elbow "up" keeps the knee above the hip-foot line (th3 < 0), the usual hexapod posture.
    Raises UnreachableTarget when the point is out of reach or needs angles past the joint limits;
    nothing is clamped silently.
    """
    target = np.asarray(target, dtype=float)
    c0, s0 = np.cos(geom.base_angle[leg]), np.sin(geom.base_angle[leg])
    rel = target - np.array([geom.base_distance[leg] * c0, geom.base_distance[leg] * s0, 0.0])
    x0, y0, z0 = c0 * rel[0] + s0 * rel[1], -s0 * rel[0] + c0 * rel[1], rel[2]
    a2, a3 = geom.femur, geom.tibia
    horizontal = np.hypot(x0, y0)
    cos3 = (horizontal**2 + z0**2 - a2**2 - a3**2) / (2.0 * a2 * a3)
    if not -1.0 <= cos3 <= 1.0:
        distance = np.hypot(horizontal, z0)
        raise UnreachableTarget(leg, target, f"distance {distance:.4f} m outside [{abs(a2 - a3):.4f}, {a2 + a3:.4f}]")
    th3 = -np.arccos(cos3) if elbow == "up" else np.arccos(cos3)
    heading = np.arctan2(y0, x0) if horizontal > 1e-12 else 0.0
    # Two shoulder branches: the leg reaching towards the foot, or turned half a turn and reaching
    # back over the hip. The first within the joint limits wins.
    candidates = [_leg_angles(heading, horizontal, z0, th3, a2, a3),
                  _leg_angles(_wrap(heading + np.pi), -horizontal, z0, th3, a2, a3)]
    for q in candidates:
        if np.all((q >= geom.lower - 1e-12) & (q <= geom.upper + 1e-12)):
            return q
    q = candidates[0]
    outside = (q < geom.lower - 1e-12) | (q > geom.upper + 1e-12)
    joint = int(np.argmax(outside))
    raise UnreachableTarget(leg, target, f"joint {joint + 1} angle {np.degrees(q[joint]):.1f} deg outside "
                                         f"[{np.degrees(geom.lower[joint]):.1f}, {np.degrees(geom.upper[joint]):.1f}]")


def _leg_angles(th1: float, reach: float, z0: float, th3: float, a2: float, a3: float) -> np.ndarray:
    th2 = np.arctan2(z0, reach) - np.arctan2(a3 * np.sin(th3), a2 + a3 * np.cos(th3))
    return np.array([th1, _wrap(th2), th3])


def _wrap(angle: float) -> float:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def inverse_kinematics_all(geom: LegGeometry, targets: np.ndarray, elbow: Elbow = "up") -> np.ndarray:
    """(18,) joint angles for (6, 3) foot targets; raises UnreachableTarget for the first bad leg."""
    return np.concatenate([inverse_kinematics(geom, leg, targets[leg], elbow) for leg in range(6)])


def nominal_stance(geom: LegGeometry, stance_radius: float, stance_height: float, foot_radius: float) -> np.ndarray:
    """(6, 3) foot-centre targets of the nominal stance: each foot `stance_radius` out along x_0i,
    the body origin `stance_height` above flat ground."""
    outward = np.column_stack([np.cos(geom.base_angle), np.sin(geom.base_angle), np.zeros(6)])
    feet = geom.base_positions + stance_radius * outward
    feet[:, 2] = -(stance_height - foot_radius)
    return feet
