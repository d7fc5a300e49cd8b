"""Phase-based gait generator: foot targets in the body frame, before inverse kinematics.

One generator serves every gait of the table below: leg i is in stance while its phase
(t / period + offset_i) mod 1 is below the duty factor, in swing otherwise (paper section 2 for the
alternating tripod). In stance a foot moves against the commanded body twist, which for a constant
forward speed is a straight line of one step length backwards in the body frame; in swing it
follows the paper's elliptic path (Figure 4) from lift-off to the next touch-down point, half a
step ahead of its neutral point: horizontally (1 - cos(pi u)) / 2 of the way, vertically
swing_height * sin(pi u), u the swing phase: an ellipse with semi-axes step/2 and swing_height.
"""

from __future__ import annotations

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
ALL_GAITS = ("stand",) + WALKING_GAITS


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
    swinging: np.ndarray        # (6,) bool
    liftoff: np.ndarray         # (6, 3) where each swing began


class GaitGenerator:
    def __init__(self, name: str, neutral: np.ndarray, period: float, swing_height: float):
        self.name = name
        self.neutral = np.asarray(neutral, dtype=float)
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
        return np.clip((self.phase(t) - self.duty) / (1.0 - self.duty), 0.0, 1.0)

    def stop(self) -> None:
        """Finish the swings under way, then keep every foot down."""
        self.stopping = True

    def step(self, t: float, dt: float, command: Twist) -> np.ndarray:
        """Advance to time t; returns (6, 3) foot targets in the body frame."""
        state = self.state
        swing = self.scheduled_swing(t)
        if self.stopping:
            swing &= state.swinging     # no new swings; running ones finish
        lifting = swing & ~state.swinging
        landing = state.swinging & ~swing
        state.liftoff[lifting] = state.feet[lifting]
        touchdown = self.neutral + 0.5 * self.stance_time * command.foot_velocity(self.neutral)
        # The last swing tick falls just short of u = 1: a landing foot ends its ellipse first.
        state.feet[landing] = touchdown[landing]
        stance = ~swing
        # A stance foot is fixed on the ground: in the body frame it moves against the body twist.
        state.feet[stance] -= command.foot_velocity(state.feet)[stance] * dt
        if swing.any():
            u = self.swing_progress(t)[swing]
            blend = (1.0 - np.cos(np.pi * u)) / 2.0
            path = state.liftoff[swing] + (touchdown[swing] - state.liftoff[swing]) * blend[:, None]
            path[:, 2] += self.swing_height * np.sin(np.pi * u)
            state.feet[swing] = path
        state.swinging = swing
        return state.feet.copy()
