"""The robot's onboard software: everything downstream of the sensors, nothing that reads truth.

Per tick: sensor samples -> estimator and leg odometry -> body twist (fixed, or walking to a
target) -> gait generator (foot targets in the body frame) -> inverse kinematics -> joint targets.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sensors.samples import EncoderSample, FootSample, ImuSample, Sample
from estimators.base import Estimate
from testbed.control.controller import Controller
from testbed.control.gait import GAITS, GaitGenerator, TerrainAdaptation, Twist
from testbed.model.kinematics import LegGeometry, elbow_sign, foot_positions, solve_legs_or_last
from testbed.control.navigation import TargetWalker
from testbed.control.odometry import GyroHeading, LegOdometry
from testbed.control.posture import (PostureController, PostureMeasurement, estimated_height, kinematic_height, pi_step,
                             tilted_targets, untilted_positions)
from testbed.control.command import Command
from testbed.control.startup import CalibrationPoses


# The swing command leads the gait clock by two servo time constants: a first-order servo tracks a
# ramp one time constant late, and the gap left when the command stops decays as exp(-t / tau), so
# at its scheduled touch-down the foot is e^-2 of a lag (0.7 mm tripod, 1.4 mm wave) from the ground.
SWING_LEAD_TIME_CONSTANTS = 2.0
STILL = Twist()
KNEE_UP = elbow_sign("up")


class Pilot(Controller):
    """The built-in controller: gait generator, optional posture loops, inverse kinematics."""

    use_posture = False

    @classmethod
    def from_config(cls, config) -> "Pilot":
        return cls(config)

    def __init__(self, config):
        self.config = config
        self.geometry = geometry = LegGeometry.from_config(config.robot)
        self.truth_attitude: tuple[float, float] | None = None   # tests only: (roll, pitch) in place of the estimate's
        self.dt = config.run.time_step
        # The gait keeps the stance the robot started in (known from its own joint angles): on a
        # slope that is the stance of a level body on that slope.
        self.posture = None
        adaptation = TerrainAdaptation.confirmation(config.gait.touchdown_search_speed, config.gait.touchdown_search_depth)
        lead = SWING_LEAD_TIME_CONSTANTS / config.robot.servo_gain
        if self.use_posture:
            self.posture = PostureController(config.posture, self.dt, height_reference=config.robot.stance_height)
            adaptation = terrain_adaptation(config)
            # The terrain adaptation lands each foot where its sensor finds ground; a leading swing
            # put more feet on the step's edge (step up, EKF: 4.4 and 4.7 deg tilt on seeds 4 and
            # 5 against 0.59 and 0.72 deg without the lead).
            lead = 0.0
        self._gait_arguments = (config.run.gait, config.gait.period(config.run.gait, GAITS.resolve(config.run.gait).period), config.gait.swing_height,
                                adaptation, lead)
        self.gait: GaitGenerator | None = None      # made by `start`, from the stance the robot starts in
        self.last_command: Command | None = None
        # encoder_feet in the gait frame, made with the posture correction of the last tick (which
        # the next tick's gait step uses); stale after an encoder sample
        self._gait_frame_feet = np.empty((6, 3))
        self._gait_frame_stale = True
        self.latest_estimate = None
        self.odometry = LegOdometry(geometry, config.robot.foot_radius)
        self.heading = GyroHeading(config.gait.still_time, config.sensors.imu.body_from_sensor)
        self.startup = CalibrationPoses.from_gait(config.gait)
        self.startup_time = self.startup.end
        self.heading_reference = 0.0
        self.walker = TargetWalker(config.gait, tuple(config.gait.target)) if config.gait.target else None
        self.walking_gait = GAITS.resolve(config.run.gait).walks
        self.foot_contact = np.ones(6, dtype=bool)
        self.ik_limited_ticks = 0
        self.ik_limited_last = False
        # The posture loops (roll, pitch, height) run in the per-tick kernel on their state and gains.
        self._posture_loops = ()
        gains = NO_LOOP_GAINS
        if self.posture is not None:
            self._posture_loops = (self.posture.roll, self.posture.pitch, self.posture.height)
            gains = tuple(value for loop in self._posture_loops for value in loop.gains)
        self._tick_constants = tick_constants(gains, geometry)

    def start(self, joint_positions: np.ndarray) -> None:
        name, period, swing_height, adaptation, lead = self._gait_arguments
        self.joint_targets = np.array(joint_positions, dtype=float)
        self.encoder_positions = self.joint_targets.copy()
        self.encoder_feet = foot_positions(self.geometry, self.encoder_positions)    # body frame, per encoder sample
        self.gait = GaitGenerator(name, self.encoder_feet.copy(), period, swing_height, adaptation, lead=lead)

    def command_details(self) -> Command | None:
        return self.last_command

    def tick(self, t: float, samples: list[Sample], estimate: Estimate | None) -> np.ndarray:
        """One control tick: gait, posture loops (on the estimate's attitude, or on
        `truth_attitude` where a test sets it), inverse kinematics."""
        if estimate is not None:
            self.latest_estimate = estimate
        self._absorb(samples)
        attitude = self.truth_attitude
        startup_time = self.startup_time
        walking = self.walking_gait and t >= startup_time
        twist = self._twist(t) if walking else STILL
        gait, gait_time = self.gait, t - startup_time
        if walking:
            feet = gait.step(gait_time, self.dt, twist, self.foot_contact, self._measured_feet())
        else:
            feet = gait.state.feet.copy()
        posture = self.posture is not None
        # The loops engage once the start-up (still, then the calibration poses) is over.
        measurement = self._posture_measurement(attitude) if posture and t >= startup_time else None
        update = measurement is not None
        roll, pitch, height_error = math.nan, math.nan, math.nan
        if update:
            roll, pitch, height = measurement
            if height is not None:
                height_error = height - self.posture.height_reference
        state = NO_LOOP_STATE
        if posture:
            r, p, h = self._posture_loops
            state = (r.integral, r.output, p.integral, p.output, h.integral, h.output)
        tilt = self.startup.body_tilt(t) if t < startup_time else (0.0, 0.0)
        feet, self.joint_targets, reachable, state = _body_targets_and_joints(
            feet, posture, update, roll, pitch, height_error, self.ik_limited_last, state, self._tick_constants, *tilt,
            self.joint_targets, self.encoder_feet, self._gait_frame_feet)
        if posture:
            r.integral, r.output, p.integral, p.output, h.integral, h.output = state
        self._gait_frame_stale = not posture
        limited = not reachable
        self.ik_limited_last = limited
        self.ik_limited_ticks += limited
        # joint_targets: a new array every tick (the IK's), never written afterwards
        self.last_command = Command(t, gait.phase(gait.clock(gait_time)), gait.state.swinging.copy(), feet,
                                    self.joint_targets, np.array([twist.vx, twist.vy, twist.wz]))
        return self.joint_targets

    def _measured_feet(self) -> np.ndarray:
        """The feet where the encoders put them, in the gait frame (the body frame without the
        posture controller)."""
        if self.posture is None:
            return self.encoder_feet
        return self.posture.to_gait_frame(self.encoder_feet) if self._gait_frame_stale else self._gait_frame_feet

    def _posture_measurement(self, attitude: tuple[float, float] | None) -> PostureMeasurement | None:
        estimate = self.latest_estimate
        if estimate is None:
            return None
        roll, pitch = attitude if attitude is not None else (estimate.roll, estimate.pitch)
        if estimate.body_height is not None:
            height = estimated_height(estimate.body_height, estimate.terrain_roll, estimate.terrain_pitch)
        else:
            stance = self.foot_contact & ~self.gait.state.swinging
            height = kinematic_height(self.geometry, self.encoder_positions, stance, roll, pitch,
                                      self.config.robot.foot_radius)
        return PostureMeasurement(roll, pitch, height)

    def _absorb(self, samples: list[Sample]) -> None:
        heading = self.heading
        for sample in samples:
            if isinstance(sample, ImuSample):
                heading.update(sample.t, sample.gyro)
            elif isinstance(sample, FootSample):
                self.foot_contact = np.asarray(sample.contact, dtype=bool)
            elif isinstance(sample, EncoderSample):
                self.encoder_positions = np.asarray(sample.positions, dtype=float)
                self.encoder_feet = foot_positions(self.geometry, self.encoder_positions)
                self._gait_frame_stale = True
                stance = self.foot_contact & ~self.gait.state.swinging
                self.odometry.update(self.encoder_positions, stance, heading.yaw)

    def _twist(self, t: float) -> Twist:
        """The body twist at time t, once walking."""
        gait = self.config.gait
        ramp = min(1.0, (t - self.startup_time) / gait.start_ramp) if gait.start_ramp > 0 else 1.0
        if self.walker is not None:
            command = self.walker.command(self.odometry.pose)
            if self.walker.arrived:
                self.gait.stop()
            return Twist(command.vx * ramp, command.vy * ramp, command.wz * ramp)
        # Hold the commanded heading against the feet's twisting on the ground.
        self.heading_reference += gait.turn_rate * ramp * self.dt
        drift = self.heading_reference - self.heading.yaw
        # numpy's arctan2 (its own SIMD code on this CPU) can differ from the C library's in the last bit
        error = float(np.arctan2(math.sin(drift), math.cos(drift)))
        correction = min(max(gait.heading_gain * error, -gait.cruise_turn_rate), gait.cruise_turn_rate)
        return Twist(gait.speed * ramp, gait.lateral_speed * ramp, gait.turn_rate * ramp + correction)


class PosturePilot(Pilot):
    """The pilot with the posture loops: body level and at its height over the terrain (docs/control.md)."""

    use_posture = True


def terrain_adaptation(config) -> TerrainAdaptation:
    posture = config.posture
    return TerrainAdaptation(posture.search_speed, posture.search_depth, posture.touchdown_phase,
                             posture.walk_plane_time_constant)


NO_LOOP_STATE = (0.0,) * 6     # (integral, output) of the roll, pitch and height loops
NO_LOOP_GAINS = (1.0,) * 12    # (kp, ki, dt, limit) of each


def tick_constants(gains: tuple[float, ...], geometry: LegGeometry) -> np.ndarray:
    """The per-tick kernel's constant arguments in one array (numba unboxes each argument, a
    tuple's items one by one): the posture loops' 12 gains, then the legs' base cosines, sines and
    distances (6 each), femur, tibia, and the joints' lower and upper limits (3 each)."""
    g = geometry
    return np.concatenate([gains, g.base_cos, g.base_sin, g.base_distance, [g.femur, g.tibia], g.lower, g.upper])


# Compiled: the posture loops, the posture correction, the start-up tilt, the inverse kinematics
# and the encoders' feet in the gait frame were some ten Python and compiled calls a tick (each
# compiled one ~1 us of dispatch and a boxed array, more in the run loop's cold caches).
@njit(cache=True)
def _body_targets_and_joints(feet, posture, update, roll, pitch, height_error, hold, state, constants, tilt_roll,
                             tilt_pitch, last, encoder_feet, gait_frame_feet):
    """With `posture`: the roll, pitch and height loops (PostureController.update: `state` their
    (integral, output) pairs, `constants` (tick_constants) their PiLoop.gains and the legs' geometry) updated with this measurement when
    `update` (a NaN height error leaves that loop as it is), then the gait-frame foot targets
    (6, 3) through their correction (PostureController.apply), and `encoder_feet` written in the
    gait frame into `gait_frame_feet` (PostureController.to_gait_frame). Then the start-up pose
    (CalibrationPoses.apply) and the joint angles, a leg out of reach keeping its `last` ones
    (joint_targets_or_last). Returns (targets, joint angles, whether every leg reached its target,
    the loops' new state)."""
    g = constants
    if posture:
        roll_integral, roll_output, pitch_integral, pitch_output, height_integral, height_output = state
        if update:
            roll_integral, roll_output = pi_step(roll_integral, roll_output, roll, hold, g[0], g[1], g[2], g[3])
            pitch_integral, pitch_output = pi_step(pitch_integral, pitch_output, pitch, hold, g[4], g[5], g[6], g[7])
            height_integral, height_output = pi_step(height_integral, height_output, height_error, hold,
                                                     g[8], g[9], g[10], g[11])
        state = (roll_integral, roll_output, pitch_integral, pitch_output, height_integral, height_output)
        feet = tilted_targets(feet, roll_output, pitch_output, height_output)
        untilted_positions(encoder_feet, roll_output, pitch_output, height_output, gait_frame_feet)
    if not (tilt_roll == 0.0 and tilt_pitch == 0.0):
        feet = tilted_targets(feet, tilt_roll, tilt_pitch, 0.0)
    joints, reachable = solve_legs_or_last(feet, g[12:18], g[18:24], g[24:30], g[30], g[31], g[32:35], g[35:38],
                                           KNEE_UP, last)
    return feet, joints, reachable, state
