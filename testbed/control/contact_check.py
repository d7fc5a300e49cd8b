"""Foot contact as the pilot uses it: the foot sensors' flags, checked against the legs' kinematics.

A foot sensor can lie: stuck on (reports ground under a foot in the air), stuck off (reports none
under a foot on the ground) or drop out (NaN forces). The gait believes the flags, so a foot stuck
on lands in mid-air (and its tripod then drops the body onto it) and one stuck off reaches down
for ground until the bottom of its workspace, lifting the body. Two kinematic facts, from the
joint encoders and the targets the pilot gave the servos, can contradict a flag:

- **held up**: the foot stands higher than where the servos would have taken it in free air (a
  first-order model of the servos, `servo_gain`, speed-limited, driven by the targets) by more
  than `block_margin` beyond what it can have moved since its encoder reading: something under
  the foot carries it; **stopped** when it stands off that model by more than `obstacle_margin`
  in any direction (a riser in its way; the model is only first order, hence the wider margin);
- **in the air**: a swinging foot neither held up nor stopped that stands higher than
  `air_height` above both the plane of the stance feet (gait frame, encoders) and the point
  where its swing began.

A flag on a foot in the air is not believed; a foot held up touches whatever its sensor says.
A working sensor reads no ground at some point of every swing (a foot that then meets a riser or
a step's top reads ground in the air, rightly): ground read in the air by a sensor that has not
read "none" since the swing began, or no ground under a foot held up, is disagreement; it adds up (and is forgotten at `forgetting` s per s of
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


class ContactLimits(NamedTuple):
    air_height: float = 0.015       # m above the stance feet's plane: the foot is in the air
    block_margin: float = 0.003     # m above the free-air servo model: the foot is held up
    obstacle_margin: float = 0.01   # m off it in any direction: something stops the foot
    fault_time: float = 0.15        # s of disagreement that marks a sensor faulty
    forgetting: float = 0.25        # s of disagreement forgotten per s of agreement
    recovery_time: float = 0.1      # s of each kind of agreement that clears the mark


class ContactCheck:
    """Per tick: `update(...)` returns the contact flags to use (6,) bool; `faulty` (6,) bool
    marks the sensors judged to lie; `faults_detected` counts the marks made."""

    def __init__(self, servo_gain: float, dt: float, encoder_period: float, foot_speed: float,
                 limits: ContactLimits = ContactLimits()):
        self.servo = ServoModel(min(1.0, servo_gain * dt), servo_gain, encoder_period, foot_speed * dt)
        self.dt, self.limits = dt, limits
        self.faulty = np.zeros(6, dtype=bool)
        self.disagreement = np.zeros(6)     # s the flag has disagreed with the kinematics (while not faulty)
        self.agreement = np.zeros((6, 2))   # s it has read no ground in the air, and ground in stance (while faulty)
        self.faults_detected = 0
        self.free = None                    # (6, 3) the feet in free air, body frame (the servo model)
        self.history = SwingHistory(np.zeros(6, dtype=np.bool_), np.ones(6, dtype=np.bool_))

    def update(self, flags: np.ndarray, forces: np.ndarray, measured: np.ndarray, gait_frame: np.ndarray,
               targets: np.ndarray, swinging: np.ndarray, landing: np.ndarray, liftoff: np.ndarray) -> np.ndarray:
        """`flags`, `forces`: the latest foot sample; `measured`: the feet where the encoders put
        them, body frame; `gait_frame`: the same in the gait frame; `targets`: the body-frame
        targets given to the servos at the last tick; `swinging`: the gait's swing legs;
        `landing`: the swings past their rising half; `liftoff`: where each swing began (gait frame)."""
        if self.free is None:
            self.free = np.array(measured, dtype=float)
        feet = FeetNow(measured, gait_frame, targets, liftoff, swinging, landing)
        contact, marked = checked_contact(flags, forces, feet, self.free, self.history, self.faulty,
                                          self.disagreement, self.agreement, self.servo, self.dt, self.limits)
        self.faults_detected += marked
        return contact


class FeetNow(NamedTuple):
    """The legs as the pilot knows them at one tick."""
    measured: np.ndarray            # (6, 3) where the encoders put the feet, body frame
    gait_frame: np.ndarray          # (6, 3) the same, gait frame
    targets: np.ndarray             # (6, 3) the servos' targets of the last tick, body frame
    liftoff: np.ndarray             # (6, 3) where each swing began, gait frame
    swinging: np.ndarray            # (6,) bool
    landing: np.ndarray             # (6,) bool: swinging, past the rising half (a touch lands the foot)


class SwingHistory(NamedTuple):
    """Per leg, updated in place: swinging at the last tick; its sensor has read no ground since
    the swing began."""
    was_swinging: np.ndarray
    released: np.ndarray


class ServoModel(NamedTuple):
    """The servos as the check models them: a foot moves towards its target at `gain` times the
    distance (first order), a share `step` of the distance per tick."""
    step: float                     # min(1, gain dt)
    gain: float                     # 1/s
    encoder_period: float           # s between encoder readings: how stale a reading can be
    max_step: float                 # m per tick at the servos' no-load speed


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
def checked_contact(flags, forces, feet, free, history, faulty, disagreement, agreement, servo, dt, limits):
    """ContactCheck.update's work: the contact flags to use, and how many sensors it marked
    faulty this tick. Moves the servo model `free` one tick towards `targets` and updates
    `faulty`, `disagreement` and `agreement` in place."""
    measured, gait_frame, targets, swinging = feet.measured, feet.gait_frame, feet.targets, feet.swinging
    was_swinging, released = history.was_swinging, history.released
    heights = stance_plane_heights(gait_frame, ~swinging)
    contact = np.zeros(6, dtype=np.bool_)
    marked = 0
    for leg in range(6):
        off = np.zeros(3)       # m the foot stands off the free-air model
        stale = np.zeros(3)     # m it can have moved since its encoder reading
        for axis in range(3):
            lag = targets[leg, axis] - free[leg, axis]
            free[leg, axis] += min(max(servo.step * lag, -servo.max_step), servo.max_step)
            off[axis] = measured[leg, axis] - free[leg, axis]
            stale[axis] = abs(servo.gain * lag) * servo.encoder_period
        held_up = off[2] - stale[2] > limits.block_margin
        blocked = held_up or (np.abs(off) - stale).max() > limits.obstacle_margin
        raised = gait_frame[leg, 2] - feet.liftoff[leg, 2]
        in_air = swinging[leg] and min(heights[leg], raised) > limits.air_height and not blocked
        dropped = not np.isfinite(forces[leg])
        # A working sensor reads no ground at some point of every swing; one that touches a
        # riser or a step's top reads ground in the air, rightly, but only after that.
        if swinging[leg] and not was_swinging[leg]:
            released[leg] = False
        released[leg] = released[leg] or not flags[leg]
        was_swinging[leg] = swinging[leg]
        disagrees = dropped or (flags[leg] and in_air and not released[leg]) or (held_up and not flags[leg])
        if not faulty[leg]:
            disagreement[leg] = disagreement[leg] + dt if disagrees else \
                max(0.0, disagreement[leg] - limits.forgetting * dt)
            if disagreement[leg] >= limits.fault_time or dropped:
                faulty[leg] = True
                agreement[leg, 0] = agreement[leg, 1] = 0.0
                marked += 1
        if not faulty[leg]:
            contact[leg] = (flags[leg] and not in_air) or held_up
            continue
        # the foot is held up, stands, or has come down to the other feet's plane
        contact[leg] = held_up or not swinging[leg] or (feet.landing[leg] and heights[leg] <= 0.0)
        # Trusted again only after it has read both: no ground in the air, ground in stance.
        if disagrees:
            agreement[leg, 0] = agreement[leg, 1] = 0.0
        elif in_air and not flags[leg]:
            agreement[leg, 0] += dt
        elif not swinging[leg] and flags[leg]:
            agreement[leg, 1] += dt
        if min(agreement[leg, 0], agreement[leg, 1]) >= limits.recovery_time:
            faulty[leg] = False
            disagreement[leg] = 0.0
    return contact, marked
