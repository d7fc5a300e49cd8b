"""The robot's onboard software: everything downstream of the sensors, nothing that reads truth.

Per tick: sensor samples -> estimator and leg odometry -> body twist (fixed, or walking to a
target) -> gait generator (foot targets in the body frame) -> inverse kinematics -> joint targets;
the planted feet's targets then roll with their spheres (`rolling.StanceRolling`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sensors.samples import EncoderSample, FootSample, ImuSample, Sample
from estimators.base import Estimate
from testbed.control.contact_check import ContactCheck
from testbed.control.controller import Controller
from testbed.control.gait import GAITS, GaitGenerator, TerrainAdaptation, Twist, rotate_frame
from testbed.model.kinematics import (LegGeometry, elbow_sign, foot_positions, joint_targets_or_last,
                                     solve_legs_or_last)
from testbed.control.navigation import TargetWalker
from testbed.control.odometry import GyroHeading, LegOdometry
from testbed.control.posture import (POSTURE_LAWS, PostureCorrection, PostureMeasurement, body_frame_targets,
                                     checked_correction, estimated_height, kinematic_height, levelling_rotation,
                                     tilted_targets, untilted_positions)
from testbed.control.command import Command
from testbed.control.rolling import StanceRolling
from testbed.model.errors import PluginFailure
from testbed.control.startup import CalibrationPoses


# The swing command leads the gait clock by two servo time constants: a first-order servo tracks a
# ramp one time constant late, and the gap left when the command stops decays as exp(-t / tau), so
# at its scheduled touch-down the foot is e^-2 of a lag (0.7 mm tripod, 1.4 mm wave) from the ground.
SWING_LEAD_TIME_CONSTANTS = 2.0
STILL = Twist()
KNEE_UP = elbow_sign("up")
# The start-up's crouch: the reach lacking in a tilted pose changes with the crouch through the
# tilt; a few fixed-point steps settle it to well under a millimetre.
CROUCH_ITERATIONS = 4
# m: a swing foot target out of its leg's reach is tried this much lower, in turn (Pilot._lower_swings_to_reach)
SWING_LOWERING = (0.0025, 0.005, 0.01, 0.015, 0.02, 0.03)


class Pilot(Controller):
    """The built-in controller: gait generator, optional posture law, inverse kinematics."""

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
        self.posture_law = None
        self.posture_law_spec = config.posture.law
        self.correction = PostureCorrection()
        adaptation = TerrainAdaptation.confirmation(config.gait.touchdown_search_speed, config.gait.touchdown_search_depth)
        lead = SWING_LEAD_TIME_CONSTANTS / config.robot.servo_gain
        if self.use_posture:
            self.posture_law = POSTURE_LAWS.build(self.posture_law_spec, config)
            adaptation = terrain_adaptation(config)
            # The terrain adaptation lands each foot where its sensor finds ground; a leading swing
            # puts more feet on a step's edge.
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
        self.startup = CalibrationPoses.from_gait(config.gait, config.run.duration)
        self.startup_time = self.startup.end
        self.heading_reference = 0.0
        self.walker = TargetWalker(config.gait, tuple(config.gait.target)) if config.gait.target else None
        self.walking_gait = GAITS.resolve(config.run.gait).walks
        self.foot_contact = np.ones(6, dtype=bool)     # the contact flags the gait uses (checked)
        self.sensor_contact = np.ones(6, dtype=bool)   # the foot sensors' latest flags
        self.foot_forces = np.zeros(6)
        self.contact_check = ContactCheck(config.robot.servo_gain, self.dt, 1.0 / config.sensors.encoder.rate,
                                          config.robot.servo_speed_limit, geometry.arrays)
        # share per tick of the gait frame's tilt that is turned out (none without a posture law)
        self.gait_level_rate = min(1.0, self.dt / config.posture.gait_level_time_constant) if self.use_posture else 0.0
        self.ik_limited_ticks = 0
        self.ik_limited_last = False
        # m the body stands lower than robot.stance_height so that every foot stays within reach
        self.crouch = 0.0
        posture = config.posture
        self.crouch_reach = geometry.femur + geometry.tibia - posture.reach_margin
        self.max_crouch = posture.max_crouch if self.use_posture else 0.0
        self.crouch_rate = min(1.0, self.dt / posture.crouch_time_constant)

    def start(self, joint_positions: np.ndarray) -> None:
        name, period, swing_height, adaptation, lead = self._gait_arguments
        self.joint_targets = np.array(joint_positions, dtype=float)
        self.encoder_positions = self.joint_targets.copy()
        self.encoder_feet = foot_positions(self.geometry, self.encoder_positions)    # body frame, per encoder sample
        self.body_targets = self.encoder_feet.copy()                                  # body frame, the last tick's
        neutral = self.encoder_feet.copy()
        self.start_rise = self._start_rise() if self.use_posture else 0.0
        neutral[:, 2] -= self.start_rise
        self.gait = GaitGenerator(name, neutral, period, swing_height, adaptation, lead=lead)
        self.rolling = StanceRolling(self.geometry, self.config.robot.foot_radius, self.joint_targets)
        self.startup_crouch = self._startup_crouch() if self.max_crouch > 0.0 else 0.0

    def _startup_crouch(self) -> float:
        """m the body stands lower through the start-up so that every foot stays within reach in
        every calibration pose (on a steep slope the downhill feet do not), at most `max_crouch`.
        The body lowers by it with its start-up rise and stays there to the end of the poses: a
        body that moved up and down while it tilts would disturb the accelerometer offset that the
        estimators learn from the poses."""
        crouch, feet = 0.0, self.gait.state.feet
        for roll, pitch in self.startup.poses:
            for _ in range(CROUCH_ITERATIONS):
                targets = tilted_targets(tilted_targets(feet, 0.0, 0.0, -crouch), roll, pitch, 0.0)
                crouch = min(max(crouch, crouch - reach_room(targets, self.geometry.arrays, self.crouch_reach)),
                             self.max_crouch)
        return crouch

    def _start_rise(self) -> float:
        """m the body rises during the start-up to stand `robot.stance_height` above its feet's
        plane (the body starts level). On rough ground the start can put it lower, close to the
        blocks under it, which the calibration poses' tilts then strike."""
        all_feet = np.ones(6, dtype=bool)
        height = kinematic_height(self.geometry, self.encoder_positions, all_feet, 0.0, 0.0,
                                  self.config.robot.foot_radius)
        return max(0.0, self.config.robot.stance_height - height)

    def command_details(self) -> Command | None:
        return self.last_command

    def arrived(self) -> bool:
        return self.walker is not None and self.walker.arrived

    def tick(self, t: float, samples: list[Sample], estimate: Estimate | None) -> np.ndarray:
        """One control tick: gait, posture law (on the estimate's attitude, or on `truth_attitude`
        where a test sets it), inverse kinematics."""
        if estimate is not None:
            self.latest_estimate = estimate
            if estimate.gyro_bias_cov is not None:
                self.heading.adopt_bias(t, estimate.gyro_bias[2], estimate.gyro_bias_cov[2, 2])
        self._absorb(samples)
        startup_time = self.startup_time
        walking = self.walking_gait and t >= startup_time
        twist = self._twist(t) if walking else STILL
        gait, gait_time = self.gait, t - startup_time
        if walking:
            measured = self._measured_feet()
            self.foot_contact = self.contact_check.update(self.sensor_contact, self.foot_forces, self.encoder_feet,
                                                          measured, self.joint_targets, gait.state_record)
            feet = gait.step(gait_time, self.dt, twist, self.foot_contact, measured)
        else:
            feet = gait.state.feet.copy()
            if t < startup_time:
                rise = self.startup.rise(t)
                feet[:, 2] += (1.0 - rise) * self.start_rise
                self.crouch = rise * self.startup_crouch
        # The law engages once the start-up (still, then the calibration poses) is over.
        if self.posture_law is not None and t >= startup_time and self.latest_estimate is not None:
            measurement = self._posture_measurement(self.truth_attitude)
            self.correction = self._posture_update(t, measurement)
            self._level_gait_frame(measurement.roll, measurement.pitch)
        tilt = self.startup.body_tilt(t) if t < startup_time else NO_TILT
        last_joints = self.joint_targets
        targets, self.joint_targets, reachable = body_targets_and_joints(
            feet, self._applied_correction(), tilt, self.geometry.arrays, last_joints, self.encoder_feet,
            self._gait_frame_feet)
        if self.max_crouch > 0.0 and t >= startup_time and self._crouch_to_reach(targets):
            # lowered: the same gait targets again, through the lower body
            targets, self.joint_targets, reachable = body_targets_and_joints(
                feet, self._applied_correction(), tilt, self.geometry.arrays, last_joints, self.encoder_feet,
                self._gait_frame_feet)
        if not reachable and walking and self.max_crouch > 0.0:
            targets, self.joint_targets, reachable = self._lower_swings_to_reach(feet, tilt, last_joints)
        feet = targets
        self.body_targets = feet
        self._gait_frame_stale = self.posture_law is None
        limited = not reachable
        self.ik_limited_last = limited
        self.ik_limited_ticks += limited
        # joint_targets: a new array every tick (the IK's), never written afterwards
        self.last_command = Command(t, gait.phase(gait.clock(gait_time)), gait.state.swinging.copy(), feet,
                                    self.joint_targets, np.array([twist.vx, twist.vy, twist.wz]))
        return self.joint_targets

    def _applied_correction(self) -> tuple[float, float, float]:
        """The law's correction with the body lowered by the crouch."""
        roll, pitch, height = self.correction
        return roll, pitch, height - self.crouch

    def _crouch_to_reach(self, targets: np.ndarray) -> bool:
        """Lower the body at once by what the foot target (body frame) nearest the edge of its
        leg's reach lacks, up to `max_crouch`; with room to spare, rise back towards
        `robot.stance_height` over `crouch_time_constant`. Whether the body was lowered.
        A level body on a ramp needs its downhill legs longer at the end of their stride, a front
        foot reaching down a step longer than the stance allows: lowering the body keeps them
        on their targets rather than at their last joint angles (IK-limited) while the body tilts."""
        room = reach_room(targets, self.geometry.arrays, self.crouch_reach)
        wanted = min(max(self.crouch - room, 0.0), self.max_crouch)
        if wanted > self.crouch:
            self.crouch = wanted
            return True
        self.crouch += (wanted - self.crouch) * self.crouch_rate
        return False

    def _lower_swings_to_reach(self, feet: np.ndarray, tilt: tuple[float, float], last_joints: np.ndarray):
        """(targets, joints, reachable) with the swing feet's targets lowered by the least of
        SWING_LOWERING's steps that lets every leg reach them: a swing raised over a step or a
        riser, the body lowered on the stairs' next tread, folds the knee past its joint limit
        (the femur's upper limit) when its foot comes up close under the hip."""
        swinging = self.gait.state.swinging
        lowered = feet.copy()
        for drop in SWING_LOWERING:
            lowered[:, 2] = np.where(swinging, feet[:, 2] - drop, feet[:, 2])
            targets, joints, reachable = body_targets_and_joints(
                lowered, self._applied_correction(), tilt, self.geometry.arrays, last_joints, self.encoder_feet,
                self._gait_frame_feet)
            if reachable:
                break
        return targets, joints, reachable

    def _level_gait_frame(self, roll: float, pitch: float) -> None:
        """Turn the gait frame towards level, by its tilt with respect to gravity (the estimated
        attitude less the correction) over `posture.gait_level_time_constant`.

        Nothing else ties the gait frame to gravity: a foot lands where the encoders put it
        through the correction, so the stance plane takes whatever tilt the correction has, and
        a bias in the landings (the servos' lag, the legs' sag) would turn the frame a little
        every step, and the correction with it, without bound (docs/control.md)."""
        if self.gait_level_rate <= 0.0:
            return
        correction = self.correction
        level_gait_frame(self.gait.state_record, roll, pitch, correction.roll, correction.pitch, self.gait_level_rate)

    def _posture_update(self, t: float, measurement: PostureMeasurement) -> PostureCorrection:
        """The law's correction; whatever it raises or returns malformed is a one-line PluginFailure."""
        try:
            correction = self.posture_law.update(t, measurement, self.latest_estimate, self.ik_limited_last)
        except Exception as error:
            raise PluginFailure(f"posture law '{self.posture_law_spec}' failed in update at run time: "
                                f"{type(error).__name__}: {error}") from None
        return checked_correction(correction, self.posture_law_spec)

    def _measured_feet(self) -> np.ndarray:
        """The feet where the encoders put them, in the gait frame (the body frame without a
        posture law)."""
        if self.posture_law is None:
            return self.encoder_feet
        if self._gait_frame_stale:
            roll, pitch, height = self._applied_correction()
            return untilted_positions(self.encoder_feet, roll, pitch, height, np.empty((6, 3)))
        return self._gait_frame_feet

    def _posture_measurement(self, attitude: tuple[float, float] | None) -> PostureMeasurement:
        estimate = self.latest_estimate
        roll, pitch = attitude if attitude is not None else (estimate.roll, estimate.pitch)
        stance = self.foot_contact & ~self.gait.state.swinging
        if np.count_nonzero(stance) < 3:
            # No support plane is measured now; an estimator's body height is its last fit's,
            # which the body has moved from since (docs/control.md, "The height at a stand").
            height = None
        elif estimate.body_height is not None:
            height = estimated_height(estimate.body_height, estimate.terrain_roll, estimate.terrain_pitch)
        else:
            height = kinematic_height(self.geometry, self.encoder_positions, stance, roll, pitch,
                                      self.config.robot.foot_radius)
        height_error = None if height is None else height - (self.config.robot.stance_height - self.crouch)
        return PostureMeasurement(roll, pitch, height_error)

    def _absorb(self, samples: list[Sample]) -> None:
        heading = self.heading
        for sample in samples:
            if isinstance(sample, ImuSample):
                heading.update(sample.t, sample.gyro)
            elif isinstance(sample, FootSample):
                self.sensor_contact = np.asarray(sample.contact, dtype=bool)
                self.foot_forces = np.asarray(sample.normal_forces, dtype=float)
                if not (self.walking_gait and sample.t >= self.startup_time):
                    self.foot_contact = self.sensor_contact
            elif isinstance(sample, EncoderSample):
                self.encoder_positions = np.asarray(sample.positions, dtype=float)
                self.encoder_feet = foot_positions(self.geometry, self.encoder_positions)
                # The planted feet's targets roll with their spheres (testbed/control/rolling.py).
                planted = ~self.gait.state.swinging & (self.walking_gait and sample.t >= self.startup_time)
                self.rolling.roll(self.gait.state.feet, self.encoder_positions, planted, self.encoder_feet)
                self._gait_frame_stale = True
                stance = self.foot_contact & ~self.gait.state.swinging
                self.odometry.update(self.encoder_positions, stance, heading.yaw)

    def _pose(self) -> tuple[float, float, float]:
        """The planar pose (x, y, yaw) in the start frame: the estimator's when it gives a position
        (a full-state estimator), else the leg odometry's with the gyro heading."""
        estimate = self.latest_estimate
        if estimate is not None and estimate.position is not None:
            return float(estimate.position[0]), float(estimate.position[1]), estimate.yaw
        return self.odometry.pose

    def _twist(self, t: float) -> Twist:
        """The body twist at time t, once walking."""
        gait = self.config.gait
        ramp = min(1.0, (t - self.startup_time) / gait.start_ramp) if gait.start_ramp > 0 else 1.0
        if self.walker is not None:
            command = self.walker.command(self._pose())
            if self.walker.arrived:
                self.gait.stop()
            return Twist(command.vx * ramp, command.vy * ramp, command.wz * ramp)
        # Hold the commanded heading against the feet's twisting on the ground, on the gyro heading:
        # a full-state estimator's yaw follows its gyro bias, which slipping feet move (at a step's
        # edge by several degrees within a second), and the loop would turn the robot on that.
        self.heading_reference += gait.turn_rate * ramp * self.dt
        drift = self.heading_reference - self.heading.yaw
        error = math.atan2(math.sin(drift), math.cos(drift))
        correction = min(max(gait.heading_gain * error, -gait.cruise_turn_rate), gait.cruise_turn_rate)
        return Twist(gait.speed * ramp, gait.lateral_speed * ramp, gait.turn_rate * ramp + correction)


class PosturePilot(Pilot):
    """The pilot with the posture law (`posture.law`): body level and at its height over the
    terrain (docs/control.md)."""

    use_posture = True


def terrain_adaptation(config) -> TerrainAdaptation:
    posture = config.posture
    return TerrainAdaptation(posture.search_speed, posture.search_depth, posture.touchdown_phase,
                             posture.walk_plane_time_constant, posture.step_clearance, posture.max_swing_height,
                             posture.edge_margin, config.gait.max_step_length, posture.slope_stance_shift,
                             posture.load_time, posture.load_preload)


NO_TILT = (0.0, 0.0)


@njit(cache=True)
def level_gait_frame(gait_state, roll, pitch, correction_roll, correction_pitch, share):
    """GaitGenerator.rotate by `levelling_rotation` (the same arguments) in one compiled call, on
    the gait's GAIT_STATE record."""
    rotate_frame(gait_state, levelling_rotation(roll, pitch, correction_roll, correction_pitch, share))


@njit(cache=True)
def reach_room(targets, legs, reach):
    """m the lowest-placed foot target (6, 3; body frame) can still move down before it leaves
    its leg's reach `reach` (m from the leg's base; negative: out of it by that much, vertically),
    the legs' geometry a LEG_ARRAYS record."""
    g = legs[0]
    room = math.inf
    for leg in range(6):
        x = targets[leg, 0] - g.base_distance[leg] * g.base_cos[leg]
        y = targets[leg, 1] - g.base_distance[leg] * g.base_sin[leg]
        across = x * x + y * y
        below = math.sqrt(reach * reach - across) if across < reach * reach else 0.0
        room = min(room, below + targets[leg, 2])
    return room


def body_targets_and_joints_readable(feet: np.ndarray, correction: PostureCorrection, tilt: tuple[float, float],
                                     geometry: LegGeometry, last: np.ndarray):
    """What the pilot's kernel computes, in plain steps: the gait-frame foot targets (6, 3) through
    the posture correction, then the start-up tilt, then the inverse kinematics (knee up; a leg out
    of reach keeps its `last` angles). Returns (targets, joint angles, whether every leg reached)."""
    targets = body_frame_targets(feet, correction)
    targets = body_frame_targets(targets, PostureCorrection(*tilt, 0.0))
    joints, reachable = joint_targets_or_last(geometry, targets, last)
    return targets, joints, reachable


# Compiled: the correction, the start-up tilt, the inverse kinematics and the encoders' feet in
# the gait frame as one call a tick (tests/testbed/test_pilot_kernel.py compares it with the
# readable function above).
@njit(cache=True)
def body_targets_and_joints(feet, correction, tilt, legs, last, encoder_feet, gait_frame_feet):
    """body_targets_and_joints_readable, with the geometry as a LEG_ARRAYS record `legs`,
    `correction` a (roll, pitch, height) tuple and `tilt` a (roll, pitch) tuple; also writes
    `encoder_feet` in the gait frame (the inverse of the correction) into `gait_frame_feet`."""
    roll, pitch, height = correction
    targets = tilted_targets(feet, roll, pitch, height)
    untilted_positions(encoder_feet, roll, pitch, height, gait_frame_feet)
    tilt_roll, tilt_pitch = tilt
    if not (tilt_roll == 0.0 and tilt_pitch == 0.0):
        targets = tilted_targets(targets, tilt_roll, tilt_pitch, 0.0)
    joints, reachable = solve_legs_or_last(targets, legs, KNEE_UP, last)
    return targets, joints, reachable
