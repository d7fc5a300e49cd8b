"""IMU preintegration between two filter steps (Forster et al. 2017, "On-Manifold Preintegration
for Real-Time Visual-Inertial Odometry", section V), compiled with numba: the 1 kHz hot path.

Between steps i and j the IMU samples are summed, in the body frame at i, into
    dR = prod Exp(w_k dt),   dv = sum dR_k a_k dt,   dp = sum (dv_k dt + dR_k a_k dt^2 / 2)
with w = gyro - b_g and a = specific force - b_a at the step's bias estimates (trapezoidal means
over each interval), and into the first-order Jacobians of (dR, dv, dp) with respect to those
biases (Forster's eq. 59 recursions). The filter then moves its state and covariance over the
whole interval at once: the mean follows every sample exactly, the covariance only at the step
rate. A specific force whose body acceleration (f - b_a - g u) lies beyond the gate is an outlier
(a spike): the last good sample is held instead, and the body acceleration's variance over the
interval is added to the velocity's.

Everything a sample touches lives in one structured record (`PREINTEGRATION`, fields by name), so
that a sample costs one compiled call. Quaternions are scalar last (x, y, z, w).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.model import spatial as rot

PREINTEGRATION = np.dtype([
    # nominal state at the last step
    ("q0", "f8", 4), ("gyro_bias", "f8", 3), ("accel_bias", "f8", 3),
    # previous sample (body frame)
    ("last_gyro", "f8", 3), ("last_accel", "f8", 3),
    # increments since the step; dt in s, extra_variance in (m/s)^2
    ("dq", "f8", 4), ("dv", "f8", 3), ("dp", "f8", 3), ("dt", "f8"), ("extra_variance", "f8"),
    # d(dR, dv, dp) / d(b_g, b_a)
    ("j_r", "f8", (3, 3)), ("j_v_g", "f8", (3, 3)), ("j_v_a", "f8", (3, 3)), ("j_p_g", "f8", (3, 3)),
    ("j_p_a", "f8", (3, 3)),
    # the specific force gate: m/s^2; the largest squared body acceleration accepted (m/s^2)^2;
    # the body acceleration's variance (m/s^2)^2
    ("gravity", "f8"), ("gate", "f8"), ("body_variance", "f8"),
])

ACCEPTED, REJECTED, MISSING = 0, 1, 2     # what became of a sample's specific force


@njit(cache=True)
def current_attitude(record: np.ndarray) -> rot.Quaternion:
    """q0 * dq: the attitude at the last sample."""
    p = record[0]
    return rot.normalized(rot.multiply((p.q0[0], p.q0[1], p.q0[2], p.q0[3]), _dq(p)))


@njit(cache=True)
def _dq(p) -> rot.Quaternion:
    return p.dq[0], p.dq[1], p.dq[2], p.dq[3]


@njit(cache=True)
def _preintegrate(record: np.ndarray, rate: np.ndarray, accel: np.ndarray, dt: float) -> None:
    """Add one interval: bias-corrected mean rate (rad/s) and specific force (m/s^2)."""
    p = record[0]
    R = rot.to_matrix(_dq(p))
    rotated = rot.matvec3(R, accel)
    accel_turn = rot.matmul3(rot.matmul3(R, rot.skew(accel)), p.j_r)     # R [a]x J_R
    half_dt2 = 0.5 * dt * dt
    for i in range(3):
        for j in range(3):
            # Position first: it reads the velocity terms before this interval (Forster eq. 59).
            p.j_p_g[i, j] += p.j_v_g[i, j] * dt - half_dt2 * accel_turn[i, j]
            p.j_p_a[i, j] += p.j_v_a[i, j] * dt - half_dt2 * R[i, j]
            p.j_v_g[i, j] -= dt * accel_turn[i, j]
            p.j_v_a[i, j] -= dt * R[i, j]
        p.dp[i] += p.dv[i] * dt + half_dt2 * rotated[i]
        p.dv[i] += rotated[i] * dt
    turn = (rate[0] * dt, rate[1] * dt, rate[2] * dt)
    step = rot.exp(turn[0], turn[1], turn[2])
    # J_R <- Exp(w dt)^T J_R - Jr(w dt) dt, with Jr(phi) = I - [phi]x / 2 to first order.
    turned = rot.matmul3(rot.to_matrix(step).T, p.j_r)
    turn_skew = rot.skew(turn)
    for i in range(3):
        for j in range(3):
            p.j_r[i, j] = turned[i, j] - dt * ((1.0 if i == j else 0.0) - 0.5 * turn_skew[i, j])
    p.dq[0], p.dq[1], p.dq[2], p.dq[3] = rot.normalized(rot.multiply(_dq(p), step))
    p.dt += dt


@njit(cache=True)
def imu_sample(record: np.ndarray, gyro: np.ndarray, accel: np.ndarray, dt: float) -> tuple:
    """One IMU sample (body frame): gate its specific force, add the interval since the previous
    sample (if dt > 0), remember the sample. A reading is missing unless it is finite. The record's `gate` is the largest squared body acceleration accepted; a
    missing or rejected sample is replaced by the last one (the body acceleration of the last good
    sample is held). Returns (status, qx, qy, qz, qw, roll, pitch, yaw) with the attitude now."""
    p = record[0]
    # The sum is finite only if every component is (as Estimator._to_body tests it).
    have_gyro = math.isfinite(gyro[0] + gyro[1] + gyro[2])
    have_accel = math.isfinite(accel[0] + accel[1] + accel[2])
    q = current_attitude(record)
    status = MISSING
    if have_accel:
        up = rot.up_in_body(q)
        excess = 0.0
        for i in range(3):
            body_accel = accel[i] - (p.accel_bias[i] + p.gravity * up[i])
            excess += body_accel * body_accel
        status = ACCEPTED if excess <= p.gate else REJECTED
    if dt > 0:
        rate, mean_accel = np.empty(3), np.empty(3)
        for i in range(3):
            # Trapezoidal means; a missing or rejected reading holds the last one.
            gyro_now = gyro[i] if have_gyro else p.last_gyro[i]
            accel_now = accel[i] if status == ACCEPTED else p.last_accel[i]
            rate[i] = 0.5 * (p.last_gyro[i] + gyro_now) - p.gyro_bias[i]
            mean_accel[i] = 0.5 * (p.last_accel[i] + accel_now) - p.accel_bias[i]
        _preintegrate(record, rate, mean_accel, dt)
        if status != ACCEPTED:
            p.extra_variance += p.body_variance * dt * dt
        q = current_attitude(record)
    if have_gyro:
        p.last_gyro[:] = gyro
    if status == ACCEPTED:
        p.last_accel[:] = accel
    roll, pitch, yaw = rot.euler_from_quaternion(q)
    return status, q[0], q[1], q[2], q[3], roll, pitch, yaw


# Compiled: one call per filter step instead of a few numpy field assignments.
@njit(cache=True)
def _start(record: np.ndarray, q: rot.Quaternion, gyro_bias: np.ndarray, accel_bias: np.ndarray) -> None:
    p = record[0]
    p.q0[:] = np.array(q)
    p.gyro_bias[:] = gyro_bias
    p.accel_bias[:] = accel_bias
    _reset(record)


@njit(cache=True)
def _reset(record: np.ndarray) -> None:
    p = record[0]
    p.dq[:] = np.array(rot.IDENTITY)
    p.dv[:] = 0.0
    p.dp[:] = 0.0
    p.dt = 0.0
    p.extra_variance = 0.0
    p.j_r[:] = 0.0
    p.j_v_g[:] = 0.0
    p.j_v_a[:] = 0.0
    p.j_p_g[:] = 0.0
    p.j_p_a[:] = 0.0


class Preintegration:
    """The record (`record`, a one-element PREINTEGRATION array, which the kernels take), and
    views of its array fields."""

    def __init__(self, gravity: float = 0.0, gate: float = math.inf, body_variance: float = 0.0):
        self.record = np.zeros(1, dtype=PREINTEGRATION)
        fields = self.record[0]
        fields["gravity"], fields["gate"], fields["body_variance"] = gravity, gate, body_variance
        self.q0, self.dq, self.dv, self.dp = fields["q0"], fields["dq"], fields["dv"], fields["dp"]
        self.j_r, self.j_v_g, self.j_v_a = fields["j_r"], fields["j_v_g"], fields["j_v_a"]
        self.j_p_g, self.j_p_a = fields["j_p_g"], fields["j_p_a"]
        self.last_gyro = fields["last_gyro"]
        self.q0[3] = 1.0
        self._dt = self.record["dt"]
        self._extra_variance = self.record["extra_variance"]
        self.reset()

    @property
    def dt(self) -> float:
        return float(self._dt[0])

    @property
    def extra_velocity_variance(self) -> float:
        """(m/s)^2 added by samples whose specific force was rejected or missing."""
        return float(self._extra_variance[0])

    def copy(self) -> "Preintegration":
        out = Preintegration()
        out.record[:] = self.record
        return out

    def start(self, q: rot.Quaternion, gyro_bias: np.ndarray, accel_bias: np.ndarray) -> None:
        """A new interval from the nominal state of a step."""
        _start(self.record, q, gyro_bias, accel_bias)

    def reset(self) -> None:
        _reset(self.record)

    def remember(self, gyro: np.ndarray | None, accel: np.ndarray | None) -> None:
        fields = self.record[0]
        if gyro is not None:
            fields["last_gyro"] = gyro
        if accel is not None:
            fields["last_accel"] = accel

    def add(self, rate: np.ndarray, accel: np.ndarray, dt: float) -> None:
        """Add one interval of bias-corrected mean rate and specific force, ungated."""
        _preintegrate(self.record, np.asarray(rate, dtype=float), np.asarray(accel, dtype=float), dt)
