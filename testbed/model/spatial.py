"""Rotations: the one toolkit of quaternion, matrix, skew, exp/log (so3) and angle helpers.

Conventions, used by every estimator:
- quaternions are Hamilton, scalar last (x, y, z, w) like scipy, and rotate body vectors into the
  world: world_from_body;
- the world is z-up, gravity along -z;
- Euler angles are ZYX (yaw-pitch-roll): R = Rz(yaw) Ry(pitch) Rx(roll), i.e. scipy's
  `as_euler("ZYX")` = (yaw, pitch, roll); nose down is positive pitch, right side down is
  positive roll;
- attitude errors are local (body-frame) rotation vectors: R_true = R_est Exp(dtheta)
  (Sola 2017, "Quaternion kinematics for the error-state Kalman filter", section 4.1 and 5).

The helpers are `register_jitable`: plain Python when called from Python, and compiled into the
numba kernels that call them (one source for both). Arrays of rotations (the UKF's sigma points,
scoring) go through scipy's `Rotation`, where the cost of building one does not matter.
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


@register_jitable
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
    out = np.empty((3, 3))     # filled entry by entry: compiled, np.array of nested lists is slow
    out[0, 0], out[0, 1], out[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    out[1, 0], out[1, 1], out[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    out[2, 0], out[2, 1], out[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return out


@register_jitable
def skew(v) -> np.ndarray:
    """[v]x, the cross-product matrix of a 3-sequence: skew(a) @ b == cross(a, b)."""
    out = np.zeros((3, 3))     # filled entry by entry, as to_matrix
    out[0, 1], out[0, 2] = -v[2], v[1]
    out[1, 0], out[1, 2] = v[2], -v[0]
    out[2, 0], out[2, 1] = -v[1], v[0]
    return out


@register_jitable
def matmul3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b for 3x3 matrices, as a plain loop: in compiled code `@` calls BLAS, whose call costs
    more than these 27 products."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@register_jitable
def matvec3(a: np.ndarray, v) -> np.ndarray:
    """a @ v for a 3x3 matrix and a 3-vector, as a plain loop (see matmul3)."""
    out = np.empty(3)
    for i in range(3):
        out[i] = a[i, 0] * v[0] + a[i, 1] * v[1] + a[i, 2] * v[2]
    return out


@register_jitable
def quaternion_from_matrix(m: np.ndarray) -> Quaternion:
    """The quaternion of a rotation matrix (Shepperd's method: the largest of w, x, y, z first,
    for accuracy), with w >= 0."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        t = 0.5 / math.sqrt(trace + 1.0)
        return normalized(((m[2, 1] - m[1, 2]) * t, (m[0, 2] - m[2, 0]) * t, (m[1, 0] - m[0, 1]) * t, 0.25 / t))
    i = 0
    if m[1, 1] > m[0, 0]:
        i = 1
    if m[2, 2] > m[i, i]:
        i = 2
    j, k = (i + 1) % 3, (i + 2) % 3
    t = math.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
    v = [0.0, 0.0, 0.0]
    v[i] = 0.5 * t
    t = 0.5 / t
    v[j] = (m[j, i] + m[i, j]) * t
    v[k] = (m[k, i] + m[i, k]) * t
    return normalized((v[0], v[1], v[2], (m[k, j] - m[j, k]) * t))


@register_jitable
def wrap_angle(angle):
    """The angle (rad, a float or an array) wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@register_jitable
def up_in_body(q: Quaternion) -> tuple[float, float, float]:
    """R^T e_z: the world's up direction in the body frame (third row of R)."""
    x, y, z, w = q
    return (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


@register_jitable
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


@register_jitable
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
    out = np.empty((3, 3))     # filled entry by entry, as to_matrix
    out[0, 0], out[0, 1], out[0, 2] = 1.0, sr * tp, cr * tp
    out[1, 0], out[1, 1], out[1, 2] = 0.0, cr, -sr
    out[2, 0], out[2, 1], out[2, 2] = 0.0, sr / cp, cr / cp
    return out


@register_jitable
def tilt_from_specific_force(fx: float, fy: float, fz: float) -> tuple[float, float]:
    """(roll, pitch) that align the body's up direction with a specific force measured at rest."""
    return math.atan2(fy, fz), math.atan2(-fx, math.sqrt(fy * fy + fz * fz))


