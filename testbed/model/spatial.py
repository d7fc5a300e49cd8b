"""Small rotation helpers for the estimators' hot paths (scipy `Rotation` costs ~10 us to build).

Conventions, used by every estimator:
- quaternions are Hamilton, scalar last (x, y, z, w) like scipy, and rotate body vectors into the
  world: world_from_body;
- the world is z-up, gravity along -z;
- Euler angles are ZYX (yaw-pitch-roll): R = Rz(yaw) Ry(pitch) Rx(roll), i.e. scipy's
  `as_euler("ZYX")` = (yaw, pitch, roll); nose down is positive pitch, right side down is
  positive roll;
- attitude errors are local (body-frame) rotation vectors: R_true = R_est Exp(dtheta)
  (Sola 2017, "Quaternion kinematics for the error-state Kalman filter", section 4.1 and 5).

The single-rotation helpers are `register_jitable`: plain Python when called from Python, and
compiled into the filters' numba kernels that call them (one source for both).
"""

from __future__ import annotations

import math

import numpy as np
from numba.extending import register_jitable

Quaternion = tuple[float, float, float, float]

IDENTITY: Quaternion = (0.0, 0.0, 0.0, 1.0)


@register_jitable
def multiply(p: Quaternion, q: Quaternion) -> Quaternion:
    """Hamilton product p * q (Sola 2017, eq. 12), scalar last."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return (pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz)


def conjugate(q: Quaternion) -> Quaternion:
    return (-q[0], -q[1], -q[2], q[3])


@register_jitable
def normalized(q: Quaternion) -> Quaternion:
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if not norm > 0 or not math.isfinite(norm):
        return IDENTITY
    sign = 1.0 if q[3] >= 0 else -1.0    # keep w >= 0: one representative per rotation
    return (sign * q[0] / norm, sign * q[1] / norm, sign * q[2] / norm, sign * q[3] / norm)


@register_jitable
def exp(rx: float, ry: float, rz: float) -> Quaternion:
    """Quaternion of the rotation vector (rx, ry, rz) (Sola 2017, eq. 101)."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < 1e-8:
        return normalized((0.5 * rx, 0.5 * ry, 0.5 * rz, 1.0))
    s = math.sin(0.5 * angle) / angle
    return (s * rx, s * ry, s * rz, math.cos(0.5 * angle))


@register_jitable
def log(q: Quaternion) -> tuple[float, float, float]:
    """Rotation vector of the quaternion q, angle in [0, pi] (Sola 2017, eq. 105)."""
    x, y, z, w = q
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    vector_norm = math.sqrt(x * x + y * y + z * z)
    if vector_norm < 1e-12:
        return (2.0 * x, 2.0 * y, 2.0 * z)
    scale = 2.0 * math.atan2(vector_norm, w) / vector_norm
    return (scale * x, scale * y, scale * z)


@register_jitable
def rotate_by_vector(q: Quaternion, rx: float, ry: float, rz: float) -> Quaternion:
    """q * Exp(r): q followed by a body-frame rotation r, normalised."""
    return normalized(multiply(q, exp(rx, ry, rz)))


@register_jitable
def to_matrix(q: Quaternion) -> np.ndarray:
    """3x3 rotation matrix of the quaternion (Sola 2017, eq. 115)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


@register_jitable
def up_in_body(q: Quaternion) -> tuple[float, float, float]:
    """R^T e_z: the world's up direction in the body frame (third row of R)."""
    x, y, z, w = q
    return (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def euler_from_quaternion(q: Quaternion) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    x, y, z, w = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - x * z))))
    return roll, pitch, yaw_of(q)


@register_jitable
def yaw_of(q: Quaternion) -> float:
    """The yaw of euler_from_quaternion alone."""
    x, y, z, w = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> Quaternion:
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return normalized((sr * cp * cy - cr * sp * sy,
                       cr * sp * cy + sr * cp * sy,
                       cr * cp * sy - sr * sp * cy,
                       cr * cp * cy + sr * sp * sy))


@register_jitable
def euler_jacobian(roll: float, pitch: float) -> np.ndarray:
    """d(roll, pitch, yaw) / d(dtheta) for a local error R Exp(dtheta).

    The inverse of the ZYX Euler-rate map omega_body = E (roll', pitch', yaw'). Its roll and pitch
    rows are orthogonal to the up direction in the body frame, so yaw uncertainty never leaks
    into roll and pitch. Near pitch +-90 deg (gimbal lock) cos(pitch) is floored to stay finite.
    """
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    if abs(cp) < 1e-6:
        cp = math.copysign(1e-6, cp)
    tp = math.sin(pitch) / cp
    return np.array([[1.0, sr * tp, cr * tp], [0.0, cr, -sr], [0.0, sr / cp, cr / cp]])


def tilt_from_specific_force(fx: float, fy: float, fz: float) -> tuple[float, float]:
    """(roll, pitch) that align the body's up direction with a specific force measured at rest."""
    return math.atan2(fy, fz), math.atan2(-fx, math.sqrt(fy * fy + fz * fz))


# -- the same operations on arrays of n quaternions / rotation vectors (sigma points) ----------

def exp_batch(rotvecs: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions of (n, 3) rotation vectors."""
    angle = np.linalg.norm(rotvecs, axis=1)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(0.5 * safe) / safe)
    return np.column_stack([scale[:, None] * rotvecs, np.cos(0.5 * angle)])


def multiply_batch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton products; either argument may be a single quaternion."""
    px, py, pz, pw = np.moveaxis(np.atleast_2d(p), 1, 0)
    qx, qy, qz, qw = np.moveaxis(np.atleast_2d(q), 1, 0)
    return np.column_stack([pw * qx + px * qw + py * qz - pz * qy,
                            pw * qy - px * qz + py * qw + pz * qx,
                            pw * qz + px * qy - py * qx + pz * qw,
                            pw * qw - px * qx - py * qy - pz * qz])


def normalized_batch(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, 3:4] < 0, -q, q)


def log_batch(q: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors of (n, 4) quaternions, angles in [0, pi]."""
    q = np.where(q[:, 3:4] < 0, -q, q)
    vector_norm = np.linalg.norm(q[:, :3], axis=1)
    small = vector_norm < 1e-12
    scale = np.where(small, 2.0, 2.0 * np.arctan2(vector_norm, q[:, 3]) / np.where(small, 1.0, vector_norm))
    return scale[:, None] * q[:, :3]


def to_matrix_batch(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
