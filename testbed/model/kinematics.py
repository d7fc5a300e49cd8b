"""Leg kinematics of the paper's hexapod: forward kinematics exactly as eq. 2, closed-form inverse
kinematics of the anthropomorphic leg (Sciavicco-Siciliano, the paper's reference [8]), and the
foot Jacobian. Everything is in the body frame O_b x_b y_b z_b; joint vectors are leg-major
(leg 1: theta_11, theta_21, theta_31; leg 2: ...), as eq. 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, NamedTuple

import numpy as np
from numba import njit

from testbed.model.robot_config import RobotConfig
from testbed.model.spatial import wrap_angle

Elbow = Literal["up", "down"]


class UnreachableTarget(ValueError):
    """A foot target that the leg cannot reach, or only outside its joint limits."""

    def __init__(self, leg: int, target: np.ndarray, reason: str):
        super().__init__(f"leg {leg + 1}: target {np.round(target, 4).tolist()} unreachable: {reason}")
        self.leg = leg
        self.target = target
        self.reason = reason


# The geometry as the compiled kernels take it: one record (a one-element structured array; a
# kernel reads `legs[0].femur`, ...), one argument however many fields.
LEG_ARRAYS = np.dtype([
    ("base_angle", "f8", 6),        # rad, theta0_i
    ("base_distance", "f8", 6),     # m, a01_i
    ("base_cos", "f8", 6),          # cos theta0_i
    ("base_sin", "f8", 6),
    ("femur", "f8"),                # m, a2
    ("tibia", "f8"),                # m, a3
    ("lower", "f8", 3),             # rad, joint limits (coxa, femur, tibia)
    ("upper", "f8", 3),
])


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

    @cached_property
    def base_cos(self) -> np.ndarray:
        """(6,) cos theta0_i, computed once: the scalar and the batched IK share these values."""
        return np.cos(self.base_angle)

    @cached_property
    def base_sin(self) -> np.ndarray:
        return np.sin(self.base_angle)

    @cached_property
    def arrays(self) -> np.ndarray:
        """The geometry as a LEG_ARRAYS record (one-element array), for the compiled kernels."""
        return leg_arrays(self.base_angle, self.base_distance, self.femur, self.tibia, self.lower, self.upper)

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


def leg_arrays(base_angle, base_distance, femur, tibia, lower, upper) -> np.ndarray:
    """A LEG_ARRAYS record of these values."""
    legs = np.empty(1, LEG_ARRAYS)
    legs["base_angle"], legs["base_distance"] = base_angle, base_distance
    legs["base_cos"], legs["base_sin"] = np.cos(base_angle), np.sin(base_angle)
    legs["femur"], legs["tibia"], legs["lower"], legs["upper"] = femur, tibia, lower, upper
    return legs


@njit(cache=True)
def rows_times_matrix(points, matrix, out):
    """out = points @ matrix for (n, 3) points and a 3x3 matrix; `out` must be another array than `points`."""
    for row in range(points.shape[0]):
        for col in range(3):
            out[row, col] = (points[row, 0] * matrix[0, col] + points[row, 1] * matrix[1, col]
                             + points[row, 2] * matrix[2, col])
    return out


def foot_positions(geom: LegGeometry, q: np.ndarray) -> np.ndarray:
    """(6, 3) foot positions p_i^b for the 18 joint angles q: eq. 2 for all legs at once."""
    return foot_positions_arrays(np.asarray(q, dtype=float).reshape(18), geom.arrays)


# Compiled: odometry, the estimators and the posture controller call it every tick or encoder sample.
@njit(cache=True)
def foot_positions_arrays(q, legs):
    """foot_positions on a LEG_ARRAYS record (compiled; callable from other kernels)."""
    g = legs[0]
    a2, a3 = g.femur, g.tibia
    feet = np.empty((6, 3))
    for leg in range(6):
        th1, th2, th3 = q[3 * leg], q[3 * leg + 1], q[3 * leg + 2]
        reach = a2 * math.cos(th2) + a3 * math.cos(th2 + th3)
        angle = g.base_angle[leg] + th1
        feet[leg, 0] = g.base_distance[leg] * g.base_cos[leg] + reach * math.cos(angle)
        feet[leg, 1] = g.base_distance[leg] * g.base_sin[leg] + reach * math.sin(angle)
        feet[leg, 2] = a2 * math.sin(th2) + a3 * math.sin(th2 + th3)
    return feet


class WorldFeet(NamedTuple):
    """Feet and tibias of the whole robot in the world frame at one instant."""
    centers: np.ndarray            # (6, 3) m, foot sphere centres
    velocities: np.ndarray         # (6, 3) m/s, of the foot sphere centres
    spins: np.ndarray              # (6, 3) rad/s, angular velocities of the tibias
    tibia_rotations: np.ndarray    # (6, 3, 3) world_from_tibia
    tibia_origins: np.ndarray      # (6, 3) m, joint-3 origins O_2i (the tibia link frames)


def world_feet(geom: LegGeometry, rotation: np.ndarray, position: np.ndarray, angular_velocity: np.ndarray,
               linear_velocity: np.ndarray, q: np.ndarray, dq: np.ndarray) -> WorldFeet:
    """Eq. 2 and its time derivative for all legs, placed at the body pose (world_from_body
    `rotation`, `position`) moving with the body's world-frame angular and linear velocity; joint
    angles and rates `q`, `dq` (18,). What DART's per-body transform and velocity getters give,
    in one compiled call instead of eighteen Python calls into DART."""
    return WorldFeet(*world_feet_of(rotation, position, angular_velocity, linear_velocity, q, dq, geom.arrays[0]))


@njit(cache=True)
def world_feet_of(rotation, position, omega, velocity, q, dq, g):
    """world_feet with the geometry `g`, any record with the fields base_angle, base_distance, femur
    and tibia (a LEG_ARRAYS element, or a kernel's own record holding them): (centers, velocities,
    spins, tibia rotations, tibia origins)."""
    base_angle, base_distance, a2, a3 = g.base_angle, g.base_distance, g.femur, g.tibia
    centers, velocities, spins = np.empty((6, 3)), np.empty((6, 3)), np.empty((6, 3))
    rotations, origins = np.empty((6, 3, 3)), np.empty((6, 3))
    local = np.empty((5, 3))    # body frame: foot, foot velocity, spin, tibia x, tibia y
    world = np.empty((5, 3))    # the same rotated into the world
    for leg in range(6):
        th1, th2, th3 = q[3 * leg], q[3 * leg + 1], q[3 * leg + 2]
        w1, w2, w23 = dq[3 * leg], dq[3 * leg + 1], dq[3 * leg + 1] + dq[3 * leg + 2]
        c0, s0 = math.cos(base_angle[leg]), math.sin(base_angle[leg])
        cp, sp = math.cos(base_angle[leg] + th1), math.sin(base_angle[leg] + th1)
        c2, s2 = math.cos(th2), math.sin(th2)
        c23, s23 = math.cos(th2 + th3), math.sin(th2 + th3)
        reach, height = a2 * c2 + a3 * c23, a2 * s2 + a3 * s23
        reach_rate, height_rate = -a2 * s2 * w2 - a3 * s23 * w23, a2 * c2 * w2 + a3 * c23 * w23
        base_x, base_y = base_distance[leg] * c0, base_distance[leg] * s0
        local[0, 0], local[0, 1], local[0, 2] = base_x + reach * cp, base_y + reach * sp, height
        local[1, 0] = reach_rate * cp - reach * sp * w1
        local[1, 1] = reach_rate * sp + reach * cp * w1
        local[1, 2] = height_rate
        local[2, 0], local[2, 1], local[2, 2] = w23 * sp, -w23 * cp, w1      # z0 w1 + z1 (w2 + w3)
        local[3, 0], local[3, 1], local[3, 2] = cp * c23, sp * c23, s23
        local[4, 0], local[4, 1], local[4, 2] = -cp * s23, -sp * s23, c23
        for r in range(5):
            for i in range(3):
                world[r, i] = rotation[i, 0] * local[r, 0] + rotation[i, 1] * local[r, 1] + rotation[i, 2] * local[r, 2]
        for i in range(3):
            centers[leg, i] = world[0, i] + position[i]
            origins[leg, i] = base_x * rotation[i, 0] + base_y * rotation[i, 1] + position[i] \
                + a2 * (c2 * (cp * rotation[i, 0] + sp * rotation[i, 1]) + s2 * rotation[i, 2])
            spins[leg, i] = omega[i] + world[2, i]
            rotations[leg, i, 0], rotations[leg, i, 1] = world[3, i], world[4, i]
            rotations[leg, i, 2] = sp * rotation[i, 0] - cp * rotation[i, 1]
        arm = world[0]
        velocities[leg, 0] = velocity[0] + omega[1] * arm[2] - omega[2] * arm[1] + world[1, 0]
        velocities[leg, 1] = velocity[1] + omega[2] * arm[0] - omega[0] * arm[2] + world[1, 1]
        velocities[leg, 2] = velocity[2] + omega[0] * arm[1] - omega[1] * arm[0] + world[1, 2]
    return centers, velocities, spins, rotations, origins


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


REACHABLE, OUT_OF_REACH, PAST_LIMITS = 0, 1, 2     # status of one leg's solution
LIMIT_TOLERANCE = 1e-12                             # rad, a joint this close past its limit is within it


def inverse_kinematics(geom: LegGeometry, leg: int, target: np.ndarray, elbow: Elbow = "up") -> np.ndarray:
    """Joint angles (th1, th2, th3) that put foot `leg` at `target` (body frame).

    elbow "up" keeps the knee above the hip-foot line (th3 < 0), the usual hexapod posture.
    Raises UnreachableTarget when the point is out of reach or needs angles past the joint limits;
    nothing is clamped silently.
    """
    target = np.asarray(target, dtype=float)
    q = np.empty(3)
    status = _solve_leg(target, leg, geom.arrays, elbow_sign(elbow), q)
    if status == REACHABLE:
        return q
    raise UnreachableTarget(leg, target, _unreachable_reason(geom, leg, target, q, status))


def inverse_kinematics_legs(geom: LegGeometry, targets: np.ndarray, fallback: np.ndarray | None = None,
                            elbow: Elbow = "up") -> tuple[np.ndarray, np.ndarray]:
    """All six legs in one compiled call: (18,) joint angles for (6, 3) foot targets and the (6,)
    bool mask of the reachable legs. A leg out of reach gets its three angles from `fallback`
    (18,), or NaN without one. The same solution as `inverse_kinematics` leg by leg."""
    fallback = np.full(18, np.nan) if fallback is None else np.asarray(fallback, dtype=float)
    q, status = _solve_legs(np.asarray(targets, dtype=float), geom.arrays, elbow_sign(elbow), fallback)
    return q, status == REACHABLE


def joint_targets_or_last(geom: LegGeometry, targets: np.ndarray, last: np.ndarray) -> tuple[np.ndarray, bool]:
    """A controller's inverse kinematics, knee up: (18,) joint angles for (6, 3) foot targets, a leg
    out of reach keeping its `last` angles, and whether every leg reached its target. The angles
    of `inverse_kinematics_legs`."""
    return solve_legs_or_last(targets, geom.arrays, elbow_sign("up"), last)


def inverse_kinematics_all(geom: LegGeometry, targets: np.ndarray, elbow: Elbow = "up") -> np.ndarray:
    """(18,) joint angles for (6, 3) foot targets; raises UnreachableTarget for the first bad leg."""
    q, reachable = inverse_kinematics_legs(geom, targets, elbow=elbow)
    if not reachable.all():
        leg = int(np.argmin(reachable))
        inverse_kinematics(geom, leg, targets[leg], elbow)     # raises with the reason
    return q


def elbow_sign(elbow: Elbow) -> float:
    return -1.0 if elbow == "up" else 1.0


def _unreachable_reason(geom: LegGeometry, leg: int, target: np.ndarray, q: np.ndarray, status: int) -> str:
    a2, a3 = geom.femur, geom.tibia
    if status == OUT_OF_REACH:
        base = np.array([geom.base_distance[leg] * geom.base_cos[leg], geom.base_distance[leg] * geom.base_sin[leg], 0.0])
        distance = np.linalg.norm(target - base)
        return f"distance {distance:.4f} m outside [{abs(a2 - a3):.4f}, {a2 + a3:.4f}]"
    outside = (q < geom.lower - LIMIT_TOLERANCE) | (q > geom.upper + LIMIT_TOLERANCE)
    joint = int(np.argmax(outside))
    return (f"joint {joint + 1} angle {np.degrees(q[joint]):.1f} deg outside "
            f"[{np.degrees(geom.lower[joint]):.1f}, {np.degrees(geom.upper[joint]):.1f}]")


# The closed form is compiled: per leg it is a dozen scalar operations, too few for numpy.
@njit(cache=True)
def _solve_leg(target, leg, legs, elbow_sign, out) -> int:
    """Leg `leg` (of the LEG_ARRAYS record `legs`) to `target` (3,), body frame: writes (th1, th2,
    th3) into `out` and returns REACHABLE, or OUT_OF_REACH (out untouched), or PAST_LIMITS (out:
    the first shoulder branch)."""
    g = legs[0]
    x, y, z = target[0], target[1], target[2]
    c0, s0, a01, a2, a3 = g.base_cos[leg], g.base_sin[leg], g.base_distance[leg], g.femur, g.tibia
    lower, upper = g.lower, g.upper
    rx, ry = x - a01 * c0, y - a01 * s0
    x0, y0 = c0 * rx + s0 * ry, -s0 * rx + c0 * ry
    horizontal = math.hypot(x0, y0)
    cos3 = (horizontal**2 + z**2 - a2**2 - a3**2) / (2.0 * a2 * a3)
    if not -1.0 <= cos3 <= 1.0:
        return OUT_OF_REACH
    th3 = elbow_sign * math.acos(cos3)
    heading = math.atan2(y0, x0) if horizontal > 1e-12 else 0.0
    knee = math.atan2(a3 * math.sin(th3), a2 + a3 * math.cos(th3))
    # Two shoulder branches: the leg reaching towards the foot, or turned half a turn and reaching
    # back over the hip. The first within the joint limits wins.
    for branch in range(2):
        th1 = heading if branch == 0 else wrap_angle(heading + math.pi)
        reach = horizontal if branch == 0 else -horizontal
        th2 = wrap_angle(math.atan2(z, reach) - knee)
        if branch == 0:
            out[0], out[1], out[2] = th1, th2, th3
        if _within(th1, lower[0], upper[0]) and _within(th2, lower[1], upper[1]) and _within(th3, lower[2], upper[2]):
            out[0], out[1], out[2] = th1, th2, th3
            return REACHABLE
    return PAST_LIMITS


@njit(cache=True)
def _solve_legs(targets, legs, elbow_sign, fallback):
    """(18,) joint angles for the (6, 3) `targets`, `fallback`'s for a leg without a solution, and
    each leg's status."""
    q = fallback.copy()
    status = np.empty(6, np.int64)
    out = np.empty(3)
    for leg in range(6):
        status[leg] = _solve_leg(targets[leg], leg, legs, elbow_sign, out)
        if status[leg] == REACHABLE:
            q[3 * leg:3 * leg + 3] = out
    return q, status


@njit(cache=True)
def solve_legs_or_last(targets, legs, elbow_sign, last):
    """joint_targets_or_last on a LEG_ARRAYS record (compiled; callable from other kernels)."""
    q, status = _solve_legs(targets, legs, elbow_sign, last)
    return q, np.all(status == REACHABLE)


@njit(cache=True)
def _within(angle, low, high) -> bool:
    return low - LIMIT_TOLERANCE <= angle <= high + LIMIT_TOLERANCE


# Compiled: the fusion filters and the pilot call it at every encoder sample.
@njit(cache=True)
def sphere_rolling_shift(positions, previous, base_angle, body_turn, up, radius):
    """(6, 3) m, how far each foot sphere's centre moves rolling without slip on ground of unit
    normal `up` (body frame) as the joints go from `previous` to `positions` (18,) rad and the body
    turns by the rotation vector `body_turn` (body frame): dphi x (r n), dphi the tibia's turn.
    `base_angle` (6,) rad: each leg's mounting angle; `radius` m: the foot sphere's."""
    shift = np.zeros((6, 3))
    for leg in range(6):
        d1 = positions[3 * leg] - previous[3 * leg]
        d23 = positions[3 * leg + 1] - previous[3 * leg + 1] + positions[3 * leg + 2] - previous[3 * leg + 2]
        if not (np.isfinite(d1) and np.isfinite(d23)):
            continue
        # th1 turns the leg about z_b; th2 + th3 tilt the tibia in the leg's vertical plane, about
        # u x z_b, u = (cos heading, sin heading, 0) (eq. 2: the foot rises with th2 + th3).
        heading = base_angle[leg] + positions[3 * leg]
        wx = body_turn[0] + d23 * math.sin(heading)
        wy = body_turn[1] - d23 * math.cos(heading)
        wz = body_turn[2] + d1
        nx, ny, nz = radius * up[0], radius * up[1], radius * up[2]
        shift[leg, 0] = wy * nz - wz * ny
        shift[leg, 1] = wz * nx - wx * nz
        shift[leg, 2] = wx * ny - wy * nx
    return shift


def nominal_stance(geom: LegGeometry, stance_radius: float, stance_height: float, foot_radius: float) -> np.ndarray:
    """(6, 3) foot-centre targets of the nominal stance: each foot `stance_radius` out along x_0i,
    the body origin `stance_height` above flat ground."""
    outward = np.column_stack([np.cos(geom.base_angle), np.sin(geom.base_angle), np.zeros(6)])
    feet = geom.base_positions + stance_radius * outward
    feet[:, 2] = -(stance_height - foot_radius)
    return feet
