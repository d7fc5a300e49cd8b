"""Foot contact as the pilot uses it: the foot sensors' flags, checked against the legs' kinematics.

A foot sensor can lie: stuck on (reports ground under a foot in the air), stuck off (reports none
under a foot on the ground) or drop out (NaN forces). The gait believes the flags, so a foot stuck
on lands in mid-air (and its tripod then drops the body onto it) and one stuck off reaches down
for ground until the bottom of its workspace, lifting the body. Two kinematic facts, from the
joint encoders and the targets the pilot gave the servos, can contradict a flag:

- **held up**: the foot stands higher than where the servos would have taken it in free air by
  more than `block_margin` beyond what it can have moved since its encoder reading: something
  under the foot carries it; **stopped** when it stands off that model by more than
  `obstacle_margin` in any direction (a riser in its way). The model is the servos' own law in
  joint space (speed proportional to the position error, `servo_gain`, saturated at the no-load
  speed) driven by the joint targets, through the legs' forward kinematics: a fast swing's feet
  lag their targets as the joints do, not as a Cartesian first-order lag would;
- **in the air**: a swinging foot neither held up nor stopped that stands higher than
  `air_height` above both the plane of the stance feet (gait frame, encoders) and the point
  where its swing began.

A foot held up touches whatever its sensor says. A working sensor reads no ground at some point
of every swing, and a foot that then meets a riser on its way up or a step's top on its way down
reads ground in the air, rightly: that flag is believed; ground read in the air by a sensor that has not
read "none" since the swing began, and since its landing part began (a riser touched on the way
up is cleared by then), or no ground under a foot held up, is disagreement; it adds up (and is forgotten at `forgetting` s per s of
agreement); at `fault_time` the sensor is marked faulty, and at once for a dropped (NaN)
reading. A marked sensor's flag is ignored: a swinging foot touches when it is held up or has
come down to the stance feet's plane, a stance foot stands. It is trusted again once it has read
both no ground in the air and ground in stance for `recovery_time` each.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.control.gait import walk_plane
from testbed.model.kinematics import foot_positions_arrays


class ContactLimits(NamedTuple):
    air_height: float = 0.015       # m above the stance feet's plane: the foot is in the air
    block_margin: float = 0.003     # m above the free-air servo model: the foot is held up
    obstacle_margin: float = 0.01   # m off it in any direction: something stops the foot
    fault_time: float = 0.15        # s of disagreement that marks a sensor faulty
    forgetting: float = 0.25        # s of disagreement forgotten per s of agreement
    recovery_time: float = 0.1      # s of each kind of agreement that clears the mark


# The check's constants and state, each one record (a one-element structured array) that the
# compiled check reads and updates by field name (flags stored as uint8).
CHECK_PARAMETERS = np.dtype([
    ("dt", "f8"),                       # s per tick
    ("servo_gain", "f8"),               # 1/s
    ("servo_speed", "f8"),              # rad/s, the servos' no-load speed
    ("encoder_period", "f8"),           # s between encoder readings: how old a reading can be
    *[(name, "f8") for name in ContactLimits._fields],
])
CHECK_STATE = np.dtype([
    ("free_joints", "f8", 18),          # the joints in free air (the servo model), rad
    ("free", "f8", (6, 3)),             # the feet there, body frame
    ("free_step", "f8", (6, 3)),        # m they moved at the last tick
    ("faulty", "u1", 6),                # sensors judged to lie
    ("disagreement", "f8", 6),          # s the flag has disagreed with the kinematics (while trusted)
    ("agreement", "f8", (6, 2)),        # s it read no ground in the air, and ground in stance (while faulty)
    ("was_swinging", "u1", 6),          # the leg swung at the last tick
    ("was_landing", "u1", 6),           # the leg's swing was in its landing part at the last tick
    ("released", "u1", 6),              # its sensor has read no ground since the swing (its landing part) began
    ("marked", "i8"),                   # sensors marked faulty so far
])


class ContactCheck:
    """Per tick: `update(...)` returns the contact flags to use (6,) bool; `faulty` (6,) bool
    marks the sensors judged to lie; `faults_detected` counts the marks made."""

    def __init__(self, servo_gain: float, dt: float, encoder_period: float, servo_speed: float, legs: np.ndarray,
                 limits: ContactLimits = ContactLimits()):
        """`legs`: the legs' geometry (a LEG_ARRAYS record, `LegGeometry.arrays`)."""
        self.legs = legs
        self.parameters = np.zeros(1, CHECK_PARAMETERS)
        for field, value in (("dt", dt), ("servo_gain", servo_gain), ("servo_speed", servo_speed),
                             ("encoder_period", encoder_period), *limits._asdict().items()):
            self.parameters[field] = value
        self.state = np.zeros(1, CHECK_STATE)
        self.state["released"] = 1
        self.faulty = self.state["faulty"][0].view(bool)
        self.disagreement = self.state["disagreement"][0]
        self._started = False

    @property
    def faults_detected(self) -> int:
        return int(self.state["marked"][0])

    def update(self, flags: np.ndarray, forces: np.ndarray, measured: np.ndarray, gait_frame: np.ndarray,
               joint_targets: np.ndarray, gait_state: np.ndarray) -> np.ndarray:
        """`flags`, `forces`: the latest foot sample; `measured`: the feet where the encoders put
        them, body frame; `gait_frame`: the same in the gait frame; `joint_targets`: the joint
        targets (18,) given to the servos at the last tick, which the joints started from at the
        first call; `gait_state`: the gait's GAIT_STATE record (which legs swing, which swings
        land, where they began)."""
        if not self._started:
            self.state["free_joints"] = joint_targets
            self.state["free"] = foot_positions_arrays(np.asarray(joint_targets, dtype=float), self.legs)
            self._started = True
        free_air_step(joint_targets, self.state, self.parameters, self.legs)
        return checked_contact(flags, forces, measured, gait_frame, gait_state, self.state, self.parameters)


@njit(cache=True)
def free_air_step(joint_targets, state, parameters, legs):
    """The servo model one tick on: each joint moves at servo_gain times its error to its target,
    at most the no-load speed (the simulated servos' law); the feet there by forward kinematics."""
    s, p = state[0], parameters[0]
    joints = s.free_joints
    for joint in range(18):
        speed = min(max(p.servo_gain * (joint_targets[joint] - joints[joint]), -p.servo_speed), p.servo_speed)
        joints[joint] += speed * p.dt
    feet = foot_positions_arrays(joints, legs)
    for leg in range(6):
        for axis in range(3):
            s.free_step[leg, axis] = feet[leg, axis] - s.free[leg, axis]
            s.free[leg, axis] = feet[leg, axis]


@njit(cache=True)
def stance_plane_heights(gait_frame, stance):
    """(6,) each foot's height above the least-squares plane of the stance feet (gait frame);
    zeros with fewer than three stance feet."""
    heights = np.zeros(6)
    if stance.sum() < 3:
        return heights
    offset, slope_x, slope_y = walk_plane(gait_frame, stance, 0.0)
    for leg in range(6):
        heights[leg] = gait_frame[leg, 2] - (offset + slope_x * gait_frame[leg, 0] + slope_y * gait_frame[leg, 1])
    return heights


@njit(cache=True)
def checked_contact(flags, forces, measured, gait_frame, gait_state, state, parameters):
    """ContactCheck.update's work after the servo model's step: the contact flags to use.
    Updates the CHECK_STATE record `state` in place."""
    g, s, p = gait_state[0], state[0], parameters[0]
    swinging, landing = g.swinging != 0, g.landing != 0
    free, faulty, disagreement, agreement = s.free, s.faulty, s.disagreement, s.agreement
    heights = stance_plane_heights(gait_frame, ~swinging)
    contact = np.zeros(6, dtype=np.bool_)
    for leg in range(6):
        off = np.zeros(3)       # m the foot stands off the free-air model
        stale = np.zeros(3)     # m it can have moved since its encoder reading
        for axis in range(3):
            off[axis] = measured[leg, axis] - free[leg, axis]
            stale[axis] = abs(s.free_step[leg, axis]) / p.dt * p.encoder_period
        held_up = off[2] - stale[2] > p.block_margin
        blocked = held_up or (np.abs(off) - stale).max() > p.obstacle_margin
        raised = gait_frame[leg, 2] - g.liftoff[leg, 2]
        in_air = swinging[leg] and min(heights[leg], raised) > p.air_height and not blocked
        dropped = not np.isfinite(forces[leg])
        # A working sensor reads no ground at some point of every swing; one that touches a
        # riser or a step's top reads ground in the air, rightly, but only after that.
        # ... and, as it comes down, in the air before its landing part: a riser touched on the
        # way up is cleared by then, a sensor stuck on reads ground on through the whole swing.
        entering_landing = swinging[leg] and landing[leg] and s.was_landing[leg] == 0
        if (swinging[leg] and s.was_swinging[leg] == 0) or entering_landing:
            s.released[leg] = 0
        if not flags[leg]:
            s.released[leg] = 1
        s.was_swinging[leg] = 1 if swinging[leg] else 0
        s.was_landing[leg] = 1 if swinging[leg] and landing[leg] else 0
        disagrees = dropped or (flags[leg] and in_air and s.released[leg] == 0) or (held_up and not flags[leg])
        if faulty[leg] == 0:
            disagreement[leg] = disagreement[leg] + p.dt if disagrees else \
                max(0.0, disagreement[leg] - p.forgetting * p.dt)
            if disagreement[leg] >= p.fault_time or dropped:
                faulty[leg] = 1
                agreement[leg, 0] = agreement[leg, 1] = 0.0
                s.marked += 1
        if faulty[leg] == 0:
            # Ground read in the air is believed from a sensor that has read no ground since the
            # swing (its landing part) began: a riser met on the way up, a step's top met on the
            # way down. Waiting for the foot to be held up or stopped there fails where the body
            # yields instead: a foot against a block's corner on the way up pushed the body back
            # and turned it; a foot on a step's top lifted the body off the other feet.
            met_in_air = in_air and s.released[leg] != 0
            contact[leg] = (flags[leg] and (not in_air or met_in_air)) or held_up
            continue
        # the foot is held up, stands, or has come down to the other feet's plane
        contact[leg] = held_up or not swinging[leg] or (landing[leg] and heights[leg] <= 0.0)
        # Trusted again only after it has read both: no ground in the air, ground in stance.
        if disagrees:
            agreement[leg, 0] = agreement[leg, 1] = 0.0
        elif in_air and not flags[leg]:
            agreement[leg, 0] += p.dt
        elif not swinging[leg] and flags[leg]:
            agreement[leg, 1] += p.dt
        if min(agreement[leg, 0], agreement[leg, 1]) >= p.recovery_time:
            faulty[leg] = 0
            disagreement[leg] = 0.0
    return contact
