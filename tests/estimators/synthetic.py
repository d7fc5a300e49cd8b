"""Synthetic ground truth and sensor samples for the estimator tests (until sensors/ lands).

A walking-like body motion is written as analytic functions of time (so velocity, acceleration
and angular rate are exact): the body rocks +-3 deg at the 1 Hz gait frequency, sways and bobs,
gets acceleration bursts of about 2 m/s^2 at every tripod touchdown and walks forward at
5 cm/s on a plane ground (flat or sloped). The motion fades in over the first second from
standing still, as a run starts. Tripod legs 1-3-5 and 2-4-6 alternate, with a short
double support; a stance foot stays fixed in the world, a swing foot moves on an arc to its next
foothold, and the joint angles come from testbed.model.kinematics' inverse kinematics.
Sensors: the IMU gives the specific force R^T (a - g_vec) (lever arm included) and the body rate
with white noise and a constant gyro bias; encoders add white noise to the joint angles and
quantise them; foot contacts are exact. Rates as the testbed's default sensors: IMU 1 kHz,
encoders 200 Hz, feet 250 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensors.samples import EncoderSample, FootSample, ImuSample
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance

GRAVITY = 9.81
ROBOT_WEIGHT = 23.0        # N, shared by the feet on the ground
GAIT_FREQUENCY = 1.0        # Hz, one tripod cycle per second
DOUBLE_SUPPORT = 0.025      # s at each tripod switch with all six feet down
ROCK_AMPLITUDE = math.radians(3.0)
FORWARD_SPEED = 0.05        # m/s
SWING_HEIGHT = 0.03         # m
TRIPODS = (np.array([0, 2, 4]), np.array([1, 3, 5]))
START_RAMP = 1.0            # s over which the body motion fades in from standing still

# BMI088-like noise densities (data sheet: accel 175 ug/sqrt(Hz), gyro 0.014 deg/s/sqrt(Hz)).
ACCEL_NOISE_DENSITY = 175e-6 * GRAVITY
GYRO_NOISE_DENSITY = math.radians(0.014)
ENCODER_NOISE_STD = 7.7e-4  # rad, before quantisation (the testbed's default encoders)
ENCODER_BITS = 12           # 2 pi / 4096 = 1.5e-3 rad per count


@dataclass(frozen=True)
class Trajectory:
    t: np.ndarray                   # (N,) s
    rotation: np.ndarray            # (N, 3, 3) world_from_body
    acceleration: np.ndarray        # (N, 3) world, of the body origin
    angular_rate: np.ndarray        # (N, 3) body frame
    joint_positions: np.ndarray     # (N, 18) rad
    contact: np.ndarray             # (N, 6) bool
    feet_world: np.ndarray          # (N, 6, 3) foot centres
    position: np.ndarray            # (N, 3) body origin
    terrain_roll: np.ndarray        # (N,) rad, support plane seen from the body heading
    terrain_pitch: np.ndarray       # (N,) rad
    body_height: np.ndarray         # (N,) m, body origin above the ground plane

    @property
    def roll_pitch_yaw(self) -> np.ndarray:
        r = self.rotation
        return np.column_stack([np.arctan2(r[:, 2, 1], r[:, 2, 2]), -np.arcsin(np.clip(r[:, 2, 0], -1, 1)),
                                np.arctan2(r[:, 1, 0], r[:, 0, 0])])


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([one, zero, zero], -1), np.stack([zero, c, -s], -1), np.stack([zero, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1), np.stack([-s, zero, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def euler_rotation(roll, pitch, yaw) -> np.ndarray:
    return _rz(np.asarray(yaw, float)) @ _ry(np.asarray(pitch, float)) @ _rx(np.asarray(roll, float))


class _Sines:
    """Sum of a_i sin(w_i t + p_i) with exact derivatives."""

    def __init__(self, terms):
        self.terms = [(a, 2 * math.pi * f, p) for a, f, p in terms]

    def value(self, t, order=0):
        total = np.zeros_like(t)
        for amplitude, omega, phase in self.terms:
            total += amplitude * omega**order * np.sin(omega * t + phase + order * math.pi / 2)
        return total


class _Bumps:
    """Gaussian position bumps d exp(-(t - t_k)^2 / 2 s^2): acceleration bursts with no net velocity."""

    def __init__(self, times, amplitudes, width):
        self.times, self.amplitudes, self.width = times, amplitudes, width

    def value(self, t, order=0):
        total = np.zeros_like(t)
        s2 = self.width**2
        for t_k, d in zip(self.times, self.amplitudes):
            u = t - t_k
            g = d * np.exp(-0.5 * u * u / s2)
            total += [g, -u / s2 * g, (u * u / s2 - 1) / s2 * g][order]
        return total


class _Linear:
    """speed * t."""

    def __init__(self, speed):
        self.speed = speed

    def value(self, t, order=0):
        return [self.speed * t, np.full_like(t, self.speed), np.zeros_like(t)][order]


class _Sum:
    def __init__(self, *terms):
        self.terms = terms

    def value(self, t, order=0):
        return sum(term.value(t, order) for term in self.terms)


class _StartRamp:
    """A term faded in from rest over `duration` s (smootherstep, so acceleration stays continuous):
    the robot stands still at t <= 0 and walks fully from t = duration."""

    def __init__(self, term, duration):
        self.term, self.duration = term, duration

    def _ramp(self, t):
        x = np.clip(t / self.duration, 0.0, 1.0)
        d = self.duration
        return (x**3 * (10 - 15 * x + 6 * x * x), 30 * x**2 * (1 - x)**2 / d, 60 * x * (1 - x) * (1 - 2 * x) / d**2)

    def value(self, t, order=0):
        r = self._ramp(t)
        f = [self.term.value(t, k) for k in range(order + 1)]
        if order == 0:
            return r[0] * f[0]
        if order == 1:
            return r[1] * f[0] + r[0] * f[1]
        return r[2] * f[0] + 2 * r[1] * f[1] + r[0] * f[2]


@dataclass(frozen=True)
class _Motion:
    slope: float
    height: float
    roll: object
    pitch: object
    yaw: object
    x: object
    y: object
    z: object

    def euler(self, t, order=0):
        return self.roll.value(t, order), self.pitch.value(t, order), self.yaw.value(t, order)

    def position(self, t, order=0):
        x = self.x.value(t, order)
        lift = self.height / math.cos(self.slope) if order == 0 else 0.0
        z = math.tan(self.slope) * x + lift + self.z.value(t, order)
        return np.column_stack([x, self.y.value(t, order), z])


def _motion(slope_deg: float, height: float, duration: float, burst: float, seed: int) -> _Motion:
    rng = np.random.default_rng(seed)
    slope = math.radians(slope_deg)
    touchdowns = np.arange(-1.0, duration + 1.0, 0.5 / GAIT_FREQUENCY)
    width = 0.03
    bumps = [_Bumps(touchdowns, burst * width**2 * rng.choice([-1.0, 1.0], len(touchdowns)), width)
             for _ in range(3)]
    sway = 1.0 / (2 * math.pi * GAIT_FREQUENCY)**2           # 1 m/s^2 lateral sway
    surge = 1.0 / (4 * math.pi * GAIT_FREQUENCY)**2          # 1 m/s^2 at twice the gait frequency
    base_pitch = -slope                                       # body parallel to the slope

    def walking(*terms):
        return _StartRamp(_Sum(*terms), START_RAMP)

    return _Motion(
        slope=slope, height=height,
        roll=walking(_Sines([(ROCK_AMPLITUDE, GAIT_FREQUENCY, 0.3), (0.3 * ROCK_AMPLITUDE, 2 * GAIT_FREQUENCY, 1.0)])),
        # The frequency-0 term is the constant pitch of a body lying parallel to the slope.
        pitch=_Sum(walking(_Sines([(ROCK_AMPLITUDE, GAIT_FREQUENCY, 1.4),
                                   (0.3 * ROCK_AMPLITUDE, 2 * GAIT_FREQUENCY, 2.0)])),
                   _Sines([(base_pitch, 0.0, math.pi / 2)])),
        yaw=walking(_Sines([(0.1, 0.1, 0.0)])),
        x=walking(_Sines([(surge, 2 * GAIT_FREQUENCY, 0.5)]), bumps[0], _Linear(FORWARD_SPEED)),
        y=walking(_Sines([(sway, GAIT_FREQUENCY, 0.0)]), bumps[1]),
        z=walking(_Sines([(surge, 2 * GAIT_FREQUENCY, 2.5)]), bumps[2]),
    )


def _body_rate(roll, pitch, roll_rate, pitch_rate, yaw_rate):
    """ZYX Euler rates to the body angular velocity."""
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    return np.column_stack([roll_rate - yaw_rate * sp,
                            pitch_rate * cr + yaw_rate * cp * sr,
                            -pitch_rate * sr + yaw_rate * cp * cr])


def _stance_intervals(leg: int, t_end: float) -> list[tuple[float, float]]:
    period = 1.0 / GAIT_FREQUENCY
    offset = 0.0 if leg in TRIPODS[0] else 0.5 * period
    starts = np.arange(offset - 2 * period, t_end + period, period)
    return [(s - DOUBLE_SUPPORT, s + 0.5 * period + DOUBLE_SUPPORT) for s in starts]


def _foothold(motion: _Motion, nominal_xy: np.ndarray, t_mid: float, foot_radius: float) -> np.ndarray:
    """Foot centre on the ground where the foot sits at its nominal place at mid-stance."""
    body = motion.position(np.array([t_mid]))[0]
    yaw = motion.yaw.value(np.array([t_mid]))[0]
    c, s = math.cos(yaw), math.sin(yaw)
    x = body[0] + c * nominal_xy[0] - s * nominal_xy[1]
    y = body[1] + s * nominal_xy[0] + c * nominal_xy[1]
    normal = np.array([-math.sin(motion.slope), 0.0, math.cos(motion.slope)])
    return np.array([x, y, math.tan(motion.slope) * x]) + foot_radius * normal


def _feet_world(motion: _Motion, t: np.ndarray, nominal: np.ndarray, foot_radius: float):
    feet = np.zeros((len(t), 6, 3))
    contact = np.zeros((len(t), 6), dtype=bool)
    normal = np.array([-math.sin(motion.slope), 0.0, math.cos(motion.slope)])
    for leg in range(6):
        intervals = _stance_intervals(leg, t[-1])
        holds = [_foothold(motion, nominal[leg, :2], 0.5 * (a + b), foot_radius) for a, b in intervals]
        for k, (start, end) in enumerate(intervals):
            down = (t >= start) & (t < end)
            feet[down, leg] = holds[k]
            contact[down, leg] = True
            if k + 1 < len(intervals):
                next_start = intervals[k + 1][0]
                up = (t >= end) & (t < next_start)
                phase = (t[up] - end) / (next_start - end)
                path = holds[k] + np.outer(phase, holds[k + 1] - holds[k])
                feet[up, leg] = path + np.outer(SWING_HEIGHT * np.sin(np.pi * phase), normal)
    return feet, contact


def walking_trajectory(geometry: LegGeometry, foot_radius: float, stance_radius: float, height: float,
                       duration: float = 20.0, rate: float = 1000.0, slope_deg: float = 0.0,
                       burst: float = 2.0, seed: int = 7) -> Trajectory:
    t = np.arange(round(duration * rate)) / rate
    motion = _motion(slope_deg, height, duration, burst, seed)
    roll, pitch, yaw = motion.euler(t)
    rates = motion.euler(t, 1)
    rotation = euler_rotation(roll, pitch, yaw)
    position = motion.position(t)
    nominal = nominal_stance(geometry, stance_radius, height, foot_radius)
    feet, contact = _feet_world(motion, t, nominal, foot_radius)
    feet_body = np.einsum("nji,nkj->nki", rotation, feet - position[:, None, :])
    joints = np.array([inverse_kinematics_all(geometry, feet_body[k]) for k in range(len(t))])
    slope = motion.slope
    normal_world = np.array([-math.sin(slope), 0.0, math.cos(slope)])
    normal_heading = np.column_stack([np.cos(yaw) * normal_world[0], -np.sin(yaw) * normal_world[0],
                                      np.full_like(t, normal_world[2])])
    return Trajectory(t=t, rotation=rotation, acceleration=motion.position(t, 2),
                      angular_rate=_body_rate(roll, pitch, *rates), joint_positions=joints, contact=contact,
                      feet_world=feet, position=position,
                      terrain_roll=np.arcsin(-normal_heading[:, 1]),
                      terrain_pitch=np.arctan2(normal_heading[:, 0], normal_heading[:, 2]),
                      body_height=position @ normal_world)


def still_trajectory(roll: float, pitch: float, yaw: float = 0.0, duration: float = 5.0, rate: float = 1000.0,
                     stance: np.ndarray | None = None, geometry: LegGeometry | None = None) -> Trajectory:
    """A robot standing still with a fixed attitude: the IMU at rest and, if `stance` (6, 3) and
    `geometry` are given, all six feet down at those body-frame positions."""
    n = round(duration * rate)
    t = np.arange(n) / rate
    rotation = np.repeat(euler_rotation(roll, pitch, yaw)[None], n, axis=0)
    zeros = np.zeros((n, 3))
    joints = np.zeros((n, 18)) if stance is None else np.tile(inverse_kinematics_all(geometry, stance), (n, 1))
    feet_world = np.zeros((n, 6, 3)) if stance is None else np.einsum("nij,kj->nki", rotation, stance)
    return Trajectory(t=t, rotation=rotation, acceleration=zeros, angular_rate=zeros, joint_positions=joints,
                      contact=np.full((n, 6), stance is not None), feet_world=feet_world, position=zeros,
                      terrain_roll=np.zeros(n), terrain_pitch=np.zeros(n), body_height=np.zeros(n))


def _smoothstep(t: np.ndarray, start: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """0 -> 1 between start and start + duration (C1), and its time derivative."""
    x = np.clip((t - start) / duration, 0.0, 1.0)
    return x * x * (3 - 2 * x), 6 * x * (1 - x) / duration


def pivoting_trajectory(geometry: LegGeometry, stance: np.ndarray, roll: float, pitch: float, yaw: float,
                        duration: float = 4.0, rate: float = 1000.0) -> Trajectory:
    """The body pivots about its origin with its six feet planted: roll from 0 during [0.5, 1.5] s,
    then pitch during [1.5, 2.5] s and yaw during [2.5, 3] s, then it holds still."""
    t = np.arange(round(duration * rate)) / rate
    ramps = [_smoothstep(t, 0.5, 1.0), _smoothstep(t, 1.5, 1.0), _smoothstep(t, 2.5, 0.5)]
    angles = [target * ramp for target, (ramp, _) in zip((roll, pitch, yaw), ramps)]
    rates = [target * speed for target, (_, speed) in zip((roll, pitch, yaw), ramps)]
    rotation = euler_rotation(*angles)
    feet_world = np.repeat(stance[None], len(t), axis=0)
    feet_body = np.einsum("nji,nkj->nki", rotation, feet_world)
    joints = np.array([inverse_kinematics_all(geometry, feet) for feet in feet_body])
    zeros = np.zeros((len(t), 3))
    return Trajectory(t=t, rotation=rotation, acceleration=zeros, angular_rate=_body_rate(*angles[:2], *rates),
                      joint_positions=joints, contact=np.ones((len(t), 6), dtype=bool), feet_world=feet_world,
                      position=zeros, terrain_roll=np.zeros(len(t)), terrain_pitch=np.zeros(len(t)),
                      body_height=np.zeros(len(t)))


@dataclass(frozen=True)
class SensorSpec:
    """Sensor errors of the synthetic samples (defaults: the testbed's default sensors, without
    the accelerometer's turn-on offset, scale-factor and misalignment errors)."""
    accel_noise_density: float = ACCEL_NOISE_DENSITY
    gyro_noise_density: float = GYRO_NOISE_DENSITY
    gyro_bias_deg_s: float = 0.5            # each axis +-this, signs drawn from the seed
    accel_bias_std: float = 0.0             # m/s^2 per axis, drawn from the seed
    encoder_noise_std: float = ENCODER_NOISE_STD
    encoder_bits: int = ENCODER_BITS
    encoder_rate: float = 200.0             # Hz
    foot_rate: float = 250.0                # Hz
    with_legs: bool = True
    body_from_imu: np.ndarray | None = None    # IMU mounting rotation
    imu_position: tuple = (0.0, 0.0, 0.0)      # m, body frame


def imu_arrays(trajectory: Trajectory, spec: SensorSpec, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(accel, gyro, gyro_bias) arrays in the IMU frame, at the IMU point."""
    rng = np.random.default_rng(seed)
    n = len(trajectory.t)
    dt = trajectory.t[1] - trajectory.t[0]
    gravity_vector = np.array([0.0, 0.0, -GRAVITY])
    accel = np.einsum("nji,nj->ni", trajectory.rotation, trajectory.acceleration - gravity_vector)
    omega = trajectory.angular_rate
    lever = np.asarray(spec.imu_position, dtype=float)
    if lever.any():
        alpha = np.gradient(omega, dt, axis=0)
        accel = accel + np.cross(alpha, lever) + np.cross(omega, np.cross(omega, lever))
    bias = math.radians(spec.gyro_bias_deg_s) * rng.choice([-1.0, 1.0], 3)
    accel = accel + rng.normal(0.0, spec.accel_noise_density / math.sqrt(dt), (n, 3))
    accel = accel + rng.normal(0.0, spec.accel_bias_std, 3)
    gyro = omega + bias + rng.normal(0.0, spec.gyro_noise_density / math.sqrt(dt), (n, 3))
    if spec.body_from_imu is not None:
        accel, gyro = accel @ spec.body_from_imu, gyro @ spec.body_from_imu    # rows: R^T v
    return accel, gyro, bias


def encoder_readings(trajectory: Trajectory, spec: SensorSpec, seed: int) -> np.ndarray:
    """Joint angles with Gaussian noise, quantised to 2 pi / 2^bits like the testbed's encoders."""
    rng = np.random.default_rng(seed + 1_000_003)
    lsb = 2 * math.pi / 2**spec.encoder_bits
    raw = trajectory.joint_positions + rng.normal(0.0, spec.encoder_noise_std, trajectory.joint_positions.shape)
    return np.rint(raw / lsb) * lsb


def _due(t: np.ndarray, rate: float) -> np.ndarray:
    """The ticks of the IMU grid at which a stream of `rate` Hz is sampled (t_k = k / rate)."""
    period = max(1, round(1.0 / ((t[1] - t[0]) * rate)))
    return np.arange(len(t)) % period == 0


def samples(trajectory: Trajectory, spec: SensorSpec = SensorSpec(), seed: int = 0,
            accel: np.ndarray | None = None, joints: np.ndarray | None = None) -> list:
    """Time-ordered samples: at each tick the IMU sample, then encoders and feet when due.

    `accel` / `joints` replace the generated arrays (fault injection)."""
    generated_accel, gyro, _ = imu_arrays(trajectory, spec, seed)
    accel = generated_accel if accel is None else accel
    out = []
    if spec.with_legs and joints is None:
        joints = encoder_readings(trajectory, spec, seed)
    encoder_due = _due(trajectory.t, spec.encoder_rate)
    foot_due = _due(trajectory.t, spec.foot_rate)
    for k, t in enumerate(trajectory.t):
        t = float(t)
        out.append(ImuSample(t, accel[k], gyro[k]))
        if spec.with_legs and encoder_due[k]:
            out.append(EncoderSample(t, joints[k]))
        if spec.with_legs and foot_due[k]:
            contact = trajectory.contact[k]
            out.append(FootSample(t, np.where(contact, ROBOT_WEIGHT / max(1, contact.sum()), 0.0), contact))
    return out
