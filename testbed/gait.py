"""Phase-based gait generator: foot targets in the body frame, before inverse kinematics.

One generator serves every gait of the table below: leg i is in stance while its phase
(t / period + offset_i) mod 1 is below the duty factor, in swing otherwise (paper section 2 for the
alternating tripod). In stance a foot moves against the commanded body twist, which for a constant
forward speed is a straight line of one step length backwards in the body frame; in swing it
follows the paper's elliptic path (Figure 4) from lift-off to the next touch-down point, half a
step ahead of its neutral point: horizontally (1 - cos(pi u)) / 2 of the way, vertically
swing_height * sin(pi u), u the swing phase: an ellipse with semi-axes step/2 and swing_height.

Touch-down confirmation (from the foot contact sensors, never truth): a swing ends when its foot
reports ground at the end of the ellipse; one that has not found it at the scheduled touch-down
keeps reaching down, a little, while the gait clock waits, so that no leg lifts before the leg it
relieves carries weight. A foot lands where it touched and its planted height then settles back
to the start stance's. The swing command runs ahead of the gait clock (two servo time constants),
so that the lagging foot itself follows the ellipse on schedule. A foot that touches something
while it rises (a step's riser) stops moving forward and keeps rising until it is clear (elevator
reflex).

With terrain adaptation (the posture controller's, from the same sensors):
a swing aims at the plane of the stance feet instead of the flat ground of the start stance, lands
where its foot sensor first reports ground in the second part of the swing, and, finding no ground
where it expected it, keeps reaching down while the gait clock waits, so that no leg lifts before
the leg it relieves carries weight; the gait frame's height follows the stance feet's plane, so
the body climbs a slope or steps down a step with the feet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Swing start of each leg as a fraction of the cycle. Legs are numbered counter-clockwise from the
# front left (1 FL, 2 ML, 3 RL, 4 RR, 5 MR, 6 FR): tripods 1-3-5 and 2-4-6.
GAIT_TABLE: dict[str, tuple[float, tuple[float, ...]]] = {
    # name: (duty factor, swing start per leg)
    "tripod": (1 / 2, (0.5, 0.0, 0.5, 0.0, 0.5, 0.0)),
    # ripple: each side a rear-to-front wave a third of a cycle apart, the sides half a cycle apart
    "ripple": (2 / 3, (2 / 3, 1 / 3, 0.0, 1 / 2, 5 / 6, 1 / 6)),
    # wave: one leg at a time, rear to front on the left, then rear to front on the right
    "wave": (5 / 6, (2 / 6, 1 / 6, 0.0, 3 / 6, 4 / 6, 5 / 6)),
}
WALKING_GAITS = tuple(GAIT_TABLE)
# s: planted feet return to the start stance's height after touch-down confirmation. Gradual, so
# that a landing does not push a foot into DART's rigid ground; short, so that on a slope (where
# this gait lands uphill feet high) the body is back on its stance within a tenth of a step.
STANCE_SETTLE_TIME = 0.05
ALL_GAITS = ("stand",) + WALKING_GAITS
# The elliptic swing rises over the first half of its progress: a touch then is an obstacle met on
# the way up (elevator reflex), not the ground to land on.
RISING_HALF = 0.5


@dataclass(frozen=True)
class Twist:
    """Commanded planar body velocity in the body frame."""
    vx: float = 0.0      # m/s forward
    vy: float = 0.0      # m/s left
    wz: float = 0.0      # rad/s counter-clockwise

    def foot_velocity(self, feet: np.ndarray) -> np.ndarray:
        """(6, 3) velocity of the body over the ground at each foot, body frame (v + w x p)."""
        return np.column_stack([self.vx - self.wz * feet[:, 1], self.vy + self.wz * feet[:, 0], np.zeros(len(feet))])


@dataclass
class GaitState:
    feet: np.ndarray            # (6, 3) current foot targets, body frame
    swinging: np.ndarray        # (6,) bool: in the air
    liftoff: np.ndarray         # (6, 3) where each swing began


@dataclass(frozen=True)
class TerrainAdaptation:
    search_speed: float         # m/s, a foot that found no ground keeps reaching down this fast
    search_depth: float         # m below the expected ground, the leg's workspace
    touchdown_phase: float      # contact after this fraction of the swing lands the foot
    plane_time_constant: float  # s, the gait frame's height follows the stance feet's plane; inf: it stays

    @property
    def follows_terrain(self) -> bool:
        return math.isfinite(self.plane_time_constant)

    @staticmethod
    def confirmation(search_speed: float, search_depth: float) -> "TerrainAdaptation":
        """Touch-down confirmation alone: a swing ends when its foot touches at the end of the
        ellipse, or after reaching down at most `search_depth` for the ground; touches earlier in
        the swing are ignored and the gait frame stays level (this gait knows no terrain)."""
        return TerrainAdaptation(search_speed, search_depth, 1.0, math.inf)


class GaitGenerator:
    def __init__(self, name: str, neutral: np.ndarray, period: float, swing_height: float,
                 adaptation: TerrainAdaptation | None = None, lead: float = 0.0):
        self.name = name
        self.lead = lead            # s, the swing command runs this far ahead of the gait clock
        self.adaptation = adaptation
        self.waited = 0.0           # s the gait clock stood still for feet searching the ground
        self.scheduled = np.zeros(6, bool)
        self.search_floor = np.full(6, -np.inf)
        self.searching = np.zeros(6, bool)     # feet reaching down for ground the clock waits for
        self.frame_drop = 0.0       # m the ground has moved down in the gait frame (walk-plane following)
        self.neutral = np.asarray(neutral, dtype=float)
        self.neutral_height = float(self.neutral[:, 2].mean())
        self.period = period
        self.swing_height = swing_height
        if name == "stand":
            self.duty, self.swing_start = 1.0, np.zeros(6)
        else:
            duty, starts = GAIT_TABLE[name]
            self.duty, self.swing_start = duty, np.asarray(starts)
        self.state = GaitState(self.neutral.copy(), np.zeros(6, bool), self.neutral.copy())
        self.stopping = False

    @property
    def stance_time(self) -> float:
        return self.duty * self.period

    def phase(self, t: float) -> np.ndarray:
        """(6,) phase of each leg in [0, 1): stance below the duty factor, swing above."""
        # Rounded to 1e-9 of a cycle so that legs whose swings meet end-to-end never overlap for a
        # tick through floating-point error at the boundary.
        return np.mod(np.round(t / self.period - self.swing_start + self.duty, 9), 1.0)

    def scheduled_swing(self, t: float) -> np.ndarray:
        if self.name == "stand":
            return np.zeros(6, bool)
        return self.phase(t) >= self.duty

    def swing_progress(self, t: float) -> np.ndarray:
        return self._progress(self.phase(t))

    def _progress(self, phase: np.ndarray) -> np.ndarray:
        """Where each swing's command is on its ellipse: the phase's share of the swing plus the
        lead, so that the lagging servos put the foot itself on the ellipse about on schedule and
        on the ground by the scheduled touch-down; the command then waits at the touch-down point."""
        swing_time = (1.0 - self.duty) * self.period
        return np.clip((phase - self.duty) / (1.0 - self.duty) + self.lead / swing_time, 0.0, 1.0)

    def stop(self) -> None:
        """Finish the swings under way, then keep every foot down."""
        self.stopping = True

    def clock(self, t: float) -> float:
        """Gait time at run time t: the time spent waiting for the ground does not count."""
        return t - self.waited

    def step(self, t: float, dt: float, command: Twist, contact: np.ndarray | None = None,
             measured: np.ndarray | None = None) -> np.ndarray:
        """Advance to time t; returns (6, 3) foot targets in the body frame. Touch-down confirmation
        and terrain adaptation use `contact` (the foot sensors) and `measured`, the feet where the
        joint encoders put them (gait frame): a foot lands where it touched, not where its lagging
        target had got to. Without `contact` the gait follows its schedule blindly."""
        if self.adaptation is not None and contact is not None:
            return self._adaptive_step(t, dt, command, np.asarray(contact, dtype=bool), measured)
        state = self.state
        swing = self.scheduled_swing(t)
        if self.stopping:
            swing &= state.swinging     # no new swings; running ones finish
        lifting = swing & ~state.swinging
        landing = state.swinging & ~swing
        state.liftoff[lifting] = state.feet[lifting]
        touchdown = self._touchdown(command)
        # The last swing tick falls just short of u = 1: a landing foot ends its ellipse first.
        state.feet[landing] = touchdown[landing]
        self._move_stance(~swing, command, dt)
        self._move_swing(self.swing_progress(t), swing, touchdown)
        state.swinging = swing
        return state.feet.copy()

    def _touchdown(self, command: Twist) -> np.ndarray:
        return self.neutral + 0.5 * self.stance_time * command.foot_velocity(self.neutral)

    def _move_stance(self, stance: np.ndarray, command: Twist, dt: float) -> None:
        # A stance foot is fixed on the ground: in the body frame it moves against the body twist.
        self.state.feet[stance] -= command.foot_velocity(self.state.feet)[stance] * dt

    def _move_swing(self, progress: np.ndarray, swing: np.ndarray, touchdown: np.ndarray) -> None:
        if swing.any():
            state = self.state
            u = progress[swing]
            blend = (1.0 - np.cos(np.pi * u)) / 2.0
            path = state.liftoff[swing] + (touchdown[swing] - state.liftoff[swing]) * blend[:, None]
            path[:, 2] += self.swing_height * np.sin(np.pi * u)
            state.feet[swing] = path

    # ------------------------------------------------------------ terrain adaptation
    def _adaptive_step(self, t: float, dt: float, command: Twist, contact: np.ndarray,
                       measured: np.ndarray | None) -> np.ndarray:
        state, adaptation = self.state, self.adaptation
        phase = self.phase(self.clock(t))       # once per tick: the controller's time budget is tight
        scheduled = phase >= self.duty
        if self.stopping:
            scheduled &= self.scheduled | state.swinging
        lifting = scheduled & ~self.scheduled
        progress = self._progress(phase)
        # Ground found in the second part of a swing, or at or after its scheduled end: land there.
        touched = state.swinging & contact & (~scheduled | (progress >= adaptation.touchdown_phase))
        if measured is not None:
            state.feet[touched] = measured[touched]     # where it touched, not where its lagging target got to
        elif not adaptation.follows_terrain:
            state.feet[touched] = self._touchdown(command)[touched]     # the ellipse's end
        state.swinging &= ~touched
        searching = state.swinging & ~scheduled
        self.searching = searching
        if searching.any():
            self._search(searching, dt)
            self.waited += dt           # the clock waits: no leg lifts, the body does not move
            return state.feet.copy()
        state.liftoff[lifting] = state.feet[lifting]
        state.swinging |= lifting
        self.scheduled = scheduled
        touchdown = self._touchdown(command)
        if adaptation.follows_terrain:
            plane = self._walk_plane()
            touchdown[:, 2] = plane[0] + touchdown[:, :2] @ plane[1:]
        self._move_stance(~state.swinging, command, dt)
        if not adaptation.follows_terrain:
            self._settle_stance(dt)
        swinging = state.swinging & scheduled
        blocked = swinging & contact & (progress < RISING_HALF)
        if blocked.any():
            self._hold_blocked(blocked, progress, touchdown, state.feet if measured is None else measured,
                               command, dt)
        self._move_swing(progress, swinging, touchdown)
        self.search_floor[state.swinging] = touchdown[state.swinging, 2] - adaptation.search_depth
        if adaptation.follows_terrain:
            self._follow_walk_plane(plane[0], dt)
        return state.feet.copy()

    def _hold_blocked(self, blocked: np.ndarray, progress: np.ndarray, touchdown: np.ndarray,
                      feet: np.ndarray, command: Twist, dt: float) -> None:
        """Elevator reflex (Cruse's Walknet): a swing foot that meets something while it rises, such
        as a step's riser, stops moving forward over the ground where it is (`feet`: the encoders')
        and keeps rising until it is clear, instead of pushing into the obstacle and being dragged
        up it. The swing's start is moved so that the rest of the ellipse begins where the foot is
        held: once clear, it goes on to its touch-down point without a jump."""
        held = feet[blocked, :2] - command.foot_velocity(feet[blocked])[:, :2] * dt
        blend = (1.0 - np.cos(np.pi * progress[blocked])) / 2.0
        self.state.liftoff[blocked, :2] = (held - touchdown[blocked, :2] * blend[:, None]) / (1.0 - blend[:, None])

    def _settle_stance(self, dt: float) -> None:
        """Without terrain following, planted feet return to the start stance's height (first
        order, STANCE_SETTLE_TIME): a foot lands where it touched, without a push, and the body
        does not drift in height or tilt from one landing to the next."""
        stance = ~self.state.swinging
        feet = self.state.feet
        feet[stance, 2] += (self.neutral[stance, 2] - feet[stance, 2]) * min(1.0, dt / STANCE_SETTLE_TIME)

    def _search(self, searching: np.ndarray, dt: float) -> None:
        """Lower the feet that found no ground; one that reaches the bottom of its workspace
        lands there (the posture controller and the stance feet carry the body)."""
        feet = self.state.feet
        feet[searching, 2] = np.maximum(feet[searching, 2] - self.adaptation.search_speed * dt,
                                        self.search_floor[searching])
        bottomed = searching & (feet[:, 2] <= self.search_floor)
        self.state.swinging &= ~bottomed

    def _walk_plane(self) -> np.ndarray:
        """(c0, cx, cy) of the stance feet's least-squares plane z = c0 + cx x + cy y (gait frame);
        the neutral stance's level with fewer than three stance feet."""
        stance = ~self.state.swinging
        if stance.sum() < 3:
            return np.array([self.neutral[:, 2].mean(), 0.0, 0.0])
        feet = self.state.feet[stance]
        design = np.ones((len(feet), 3))
        design[:, 1:] = feet[:, :2]
        # Normal equations of at most six points: a 3x3 solve, a fifth of lstsq's cost per tick.
        return np.linalg.solve(design.T @ design, design.T @ feet[:, 2])

    def _follow_walk_plane(self, plane_height: float, dt: float) -> None:
        """Move the gait frame vertically so that the stance feet's plane returns to the neutral
        stance's height under the body (first order, plane_time_constant): on a slope the body
        climbs with the feet, after a step it settles on the new level."""
        offset = plane_height - self.neutral_height
        shift = offset * min(1.0, dt / self.adaptation.plane_time_constant)
        self.state.feet[:, 2] -= shift
        self.state.liftoff[:, 2] -= shift
        self.search_floor -= shift
        self.frame_drop += shift
