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
from typing import NamedTuple

import numpy as np
from numba import njit

from testbed.model.kinematics import fused_multiply_add
from testbed.model.registry import Registry



@dataclass(frozen=True)
class GaitPattern:
    """Which legs swing when: leg i is in stance while its phase (t / period + offset_i) mod 1 is
    below the duty factor. `period` (s) is the cycle's default length; the config's
    `gait.<name>_period` replaces it for the built-in gaits."""
    duty: float
    swing_start: tuple[float, ...]      # per leg, fraction of the cycle at which its swing starts
    period: float = 1.0

    def __post_init__(self) -> None:
        if not (0.0 < self.duty <= 1.0 and len(self.swing_start) == 6):
            raise ValueError("a gait needs a duty factor in (0, 1] and one swing start per leg")

    @property
    def walks(self) -> bool:
        return self.duty < 1.0


# Legs are numbered counter-clockwise from the front left (1 FL, 2 ML, 3 RL, 4 RR, 5 MR, 6 FR).
STAND = GaitPattern(1.0, (0.0,) * 6)
# tripods 1-3-5 and 2-4-6 (paper section 2)
TRIPOD = GaitPattern(1 / 2, (0.5, 0.0, 0.5, 0.0, 0.5, 0.0))
# ripple: each side a rear-to-front wave a third of a cycle apart, the sides half a cycle apart
RIPPLE = GaitPattern(2 / 3, (2 / 3, 1 / 3, 0.0, 1 / 2, 5 / 6, 1 / 6), period=1.2)
# wave: one leg at a time, rear to front on the left, then rear to front on the right
WAVE = GaitPattern(5 / 6, (2 / 6, 1 / 6, 0.0, 3 / 6, 4 / 6, 5 / 6), period=1.5)
GAITS = Registry("gait", "gaits", lambda obj: isinstance(obj, GaitPattern), "a testbed.control.gait.GaitPattern")
# s: planted feet return to the start stance's height after touch-down confirmation. Gradual, so
# that a landing does not push a foot into DART's rigid ground; short, so that on a slope (where
# this gait lands uphill feet high) the body is back on its stance within a tenth of a step.
STANCE_SETTLE_TIME = 0.05
# The elliptic swing rises over the first half of its progress: a touch then is an obstacle met on
# the way up (elevator reflex), not the ground to land on.
RISING_HALF = 0.5


class Twist(NamedTuple):
    """Commanded planar body velocity in the body frame. (A named tuple: one is built per tick.)"""
    vx: float = 0.0      # m/s forward
    vy: float = 0.0      # m/s left
    wz: float = 0.0      # rad/s counter-clockwise

    def foot_velocity(self, feet: np.ndarray) -> np.ndarray:
        """(n, 3) velocity of the body over the ground at each foot, body frame (v + w x p)."""
        return _foot_velocity(np.asarray(feet, dtype=float), self.vx, self.vy, self.wz)


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
    """The gait's state lives in arrays that one compiled function per tick updates in place
    (`_adaptive_step`, `_blind_step`). Compiled because the same steps as numpy code on (6, 3)
    arrays cost 78 us a tick (some 30 calls on six feet and a 3x3 solve) against 4 us; they give
    the same numbers bit for bit."""

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
        self.pattern = pattern = GAITS.resolve(name)
        self.duty, self.swing_start = pattern.duty, np.asarray(pattern.swing_start, dtype=float)
        self.state = GaitState(self.neutral.copy(), np.zeros(6, bool), self.neutral.copy())
        self.stopping = False
        self._stepped_phase = (math.nan, np.zeros(6))     # (gait time, phase) of the last step
        if adaptation is not None:
            # The adaptive step's constant scalars in one array (numba unboxes each argument).
            self._adaptive_constants = np.array([
                period, self.duty, lead, self.stance_time, swing_height, self.neutral_height, adaptation.search_speed,
                adaptation.search_depth, adaptation.touchdown_phase, adaptation.plane_time_constant])

    @property
    def stance_time(self) -> float:
        return self.duty * self.period

    def phase(self, t: float) -> np.ndarray:
        """(6,) phase of each leg in [0, 1): stance below the duty factor, swing above. At the
        last step's gait time, that step's array (never written again: a new one per step)."""
        stepped_time, stepped_phase = self._stepped_phase
        if t == stepped_time:
            return stepped_phase
        return _phase(t, self.period, self.swing_start, self.duty, np.empty(6))

    def scheduled_swing(self, t: float) -> np.ndarray:
        if not self.pattern.walks:
            return np.zeros(6, bool)
        return self.phase(t) >= self.duty

    def swing_progress(self, t: float) -> np.ndarray:
        return _progress(self.phase(t), self.duty, self.period, self.lead, np.empty(6))

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
        state, phase = self.state, np.empty(6)
        if self.adaptation is None or contact is None:
            _blind_step(t, dt, command.vx, command.vy, command.wz, self.pattern.walks, self.stopping,
                        self.period, self.swing_start, self.duty, self.lead, self.stance_time, self.swing_height,
                        self.neutral, phase, state.feet, state.swinging, state.liftoff)
            self._stepped_phase = (t, phase)
            return state.feet.copy()
        adaptation = self.adaptation
        has_measured = measured is not None
        gait_time = self.clock(t)
        searched, plane_shift = _adaptive_step(
            gait_time, dt, command.vx, command.vy, command.wz, np.asarray(contact, dtype=bool),
            measured if has_measured else state.feet, has_measured, self.stopping, self._adaptive_constants,
            self.swing_start, self.neutral, phase, state.feet, state.swinging, state.liftoff, self.scheduled,
            self.search_floor, self.searching)
        self._stepped_phase = (gait_time, phase)
        if searched:
            self.waited += dt           # the clock waits: no leg lifts, the body does not move
        elif adaptation.follows_terrain:
            self.frame_drop += plane_shift
        return state.feet.copy()


# ------------------------------------------------------------------ compiled steps
# One call per tick with the gait's arrays, updated in place. Same operations in the same order as
# numpy code on the whole arrays; the walk plane's sums and solve as numpy's BLAS and LAPACK do them.

@njit(cache=True)
def _phase(t, period, swing_start, duty, out):
    for leg in range(6):
        # Rounded to 1e-9 of a cycle (as np.round: rint of the scaled value) so that legs whose
        # swings meet end-to-end never overlap for a tick through floating-point error at the boundary.
        out[leg] = (np.rint((t / period - swing_start[leg] + duty) * 1e9) / 1e9) % 1.0
    return out


@njit(cache=True)
def _progress(phase, duty, period, lead, out):
    """Where each swing's command is on its ellipse: the phase's share of the swing plus the
    lead, so that the lagging servos put the foot itself on the ellipse about on schedule and
    on the ground by the scheduled touch-down; the command then waits at the touch-down point."""
    ahead = lead / ((1.0 - duty) * period)
    for leg in range(6):
        share = (phase[leg] - duty) / (1.0 - duty) + ahead
        share = share if share > 0.0 else 0.0       # np.clip's order: max, then min
        out[leg] = share if share < 1.0 else 1.0
    return out


@njit(cache=True)
def _ground_velocity(x, y, vx, vy, wz):
    """(x, y) velocity of the body over the ground at the point (x, y), body frame: v + w x p."""
    return vx - wz * y, vy + wz * x


@njit(cache=True)
def _foot_velocity(feet, vx, vy, wz):
    velocity = np.zeros((len(feet), 3))
    for leg in range(len(feet)):
        velocity[leg, 0], velocity[leg, 1] = _ground_velocity(feet[leg, 0], feet[leg, 1], vx, vy, wz)
    return velocity


@njit(cache=True)
def _touchdown(neutral, stance_time, vx, vy, wz):
    """Half a step ahead of the neutral point, for the current command."""
    return neutral + 0.5 * stance_time * _foot_velocity(neutral, vx, vy, wz)


@njit(cache=True)
def _move_stance(feet, stance, vx, vy, wz, dt):
    # A stance foot is fixed on the ground: in the body frame it moves against the body twist.
    for leg in range(6):
        if stance[leg]:
            velocity_x, velocity_y = _ground_velocity(feet[leg, 0], feet[leg, 1], vx, vy, wz)
            feet[leg, 0] -= velocity_x * dt
            feet[leg, 1] -= velocity_y * dt


@njit(cache=True)
def _swing_blend(progress):
    """How far along the ellipse the swing is horizontally, 0 at lift-off, 1 at touch-down."""
    return (1.0 - math.cos(math.pi * progress)) / 2.0


@njit(cache=True)
def _move_swing(feet, liftoff, progress, swing, touchdown, swing_height):
    for leg in range(6):
        if swing[leg]:
            blend = _swing_blend(progress[leg])
            for axis in range(3):
                feet[leg, axis] = liftoff[leg, axis] + (touchdown[leg, axis] - liftoff[leg, axis]) * blend
            feet[leg, 2] += swing_height * math.sin(math.pi * progress[leg])


@njit(cache=True)
def _blind_step(t, dt, vx, vy, wz, walking, stopping, period, swing_start, duty, lead, stance_time, swing_height,
                neutral, phase, feet, swinging, liftoff):
    """The gait on its schedule alone: no foot sensors, no terrain. `phase` receives the legs' phases."""
    _phase(t, period, swing_start, duty, phase)
    swing = phase >= duty
    if not walking:
        swing[:] = False
    if stopping:
        swing &= swinging       # no new swings; running ones finish
    touchdown = _touchdown(neutral, stance_time, vx, vy, wz)
    for leg in range(6):
        if swing[leg] and not swinging[leg]:
            liftoff[leg] = feet[leg]
        elif swinging[leg] and not swing[leg]:
            # The last swing tick falls just short of u = 1: a landing foot ends its ellipse first.
            feet[leg] = touchdown[leg]
    _move_stance(feet, ~swing, vx, vy, wz, dt)
    if swing.any():
        _move_swing(feet, liftoff, _progress(phase, duty, period, lead, np.empty(6)), swing, touchdown, swing_height)
    swinging[:] = swing


@njit(cache=True)
def _adaptive_step(t, dt, vx, vy, wz, contact, measured, has_measured, stopping, constants, swing_start, neutral,
                   phase, feet, swinging, liftoff, scheduled, search_floor, searching):
    """The gait with touch-down confirmation and terrain adaptation, at gait time t (`phase`
    receives the legs' phases). `constants`: period, duty, lead, stance time, swing height,
    neutral height, then the adaptation's search speed, search depth, touch-down phase and walk
    plane time constant. Returns (whether feet searched the ground, so that the clock waited; the
    gait frame's vertical shift)."""
    period, duty, lead, stance_time, swing_height, neutral_height = constants[0:6]
    search_speed, search_depth, touchdown_phase, plane_time_constant = constants[6:10]
    follows_terrain = math.isfinite(plane_time_constant)
    _phase(t, period, swing_start, duty, phase)
    now = phase >= duty
    if stopping:
        now &= scheduled | swinging
    lifting = now & ~scheduled
    progress = _progress(phase, duty, period, lead, np.empty(6))
    # Ground found in the second part of a swing, or at or after its scheduled end: land there.
    touched = swinging & contact & (~now | (progress >= touchdown_phase))
    if has_measured:
        _copy_rows(feet, measured, touched)     # where it touched, not where its lagging target got to
    elif not follows_terrain:
        _copy_rows(feet, _touchdown(neutral, stance_time, vx, vy, wz), touched)     # the ellipse's end
    swinging &= ~touched
    searching[:] = swinging & ~now
    if searching.any():
        _search(feet, swinging, searching, search_floor, search_speed * dt)
        return True, 0.0
    _copy_rows(liftoff, feet, lifting)
    swinging |= lifting
    scheduled[:] = now
    touchdown = _touchdown(neutral, stance_time, vx, vy, wz)
    plane_height = 0.0
    if follows_terrain:
        plane_height, slope_x, slope_y = _walk_plane(feet, ~swinging, neutral_height)
        for leg in range(6):
            # numpy's (6, 2) @ (2,) of strided rows: OpenBLAS's dgemv sums the second product first.
            touchdown[leg, 2] = plane_height + fused_multiply_add(touchdown[leg, 0], slope_x,
                                                                  touchdown[leg, 1] * slope_y)
    _move_stance(feet, ~swinging, vx, vy, wz, dt)
    if not follows_terrain:
        _settle_stance(feet, swinging, neutral, dt)
    in_swing = swinging & now
    blocked = in_swing & contact & (progress < RISING_HALF)
    if blocked.any():
        _hold_blocked(liftoff, blocked, progress, touchdown, measured if has_measured else feet, vx, vy, wz, dt)
    _move_swing(feet, liftoff, progress, in_swing, touchdown, swing_height)
    for leg in range(6):
        if swinging[leg]:
            search_floor[leg] = touchdown[leg, 2] - search_depth
    if not follows_terrain:
        return False, 0.0
    return False, _follow_walk_plane(feet, liftoff, search_floor, plane_height - neutral_height,
                                     min(1.0, dt / plane_time_constant))


@njit(cache=True)
def _copy_rows(target, source, rows):
    for leg in range(6):
        if rows[leg]:
            target[leg] = source[leg]


@njit(cache=True)
def _hold_blocked(liftoff, blocked, progress, touchdown, feet, vx, vy, wz, dt):
    """Elevator reflex (Cruse's Walknet): a swing foot that meets something while it rises, such
    as a step's riser, stops moving forward over the ground where it is (`feet`: the encoders')
    and keeps rising until it is clear, instead of pushing into the obstacle and being dragged
    up it. The swing's start is moved so that the rest of the ellipse begins where the foot is
    held: once clear, it goes on to its touch-down point without a jump."""
    for leg in range(6):
        if blocked[leg]:
            velocity_x, velocity_y = _ground_velocity(feet[leg, 0], feet[leg, 1], vx, vy, wz)
            held_x, held_y = feet[leg, 0] - velocity_x * dt, feet[leg, 1] - velocity_y * dt
            blend = _swing_blend(progress[leg])
            liftoff[leg, 0] = (held_x - touchdown[leg, 0] * blend) / (1.0 - blend)
            liftoff[leg, 1] = (held_y - touchdown[leg, 1] * blend) / (1.0 - blend)


@njit(cache=True)
def _settle_stance(feet, swinging, neutral, dt):
    """Without terrain following, planted feet return to the start stance's height (first
    order, STANCE_SETTLE_TIME): a foot lands where it touched, without a push, and the body
    does not drift in height or tilt from one landing to the next."""
    rate = min(1.0, dt / STANCE_SETTLE_TIME)
    for leg in range(6):
        if not swinging[leg]:
            feet[leg, 2] += (neutral[leg, 2] - feet[leg, 2]) * rate


@njit(cache=True)
def _search(feet, swinging, searching, search_floor, drop):
    """Lower the feet that found no ground; one that reaches the bottom of its workspace
    lands there (the posture controller and the stance feet carry the body)."""
    for leg in range(6):
        if searching[leg]:
            lowered = feet[leg, 2] - drop
            keep = lowered >= search_floor[leg] or math.isnan(lowered)      # np.maximum, NaN included
            feet[leg, 2] = lowered if keep else search_floor[leg]
            if feet[leg, 2] <= search_floor[leg]:
                swinging[leg] = False


@njit(cache=True)
def _walk_plane(feet, stance, neutral_height):
    """(c0, cx, cy) of the stance feet's least-squares plane z = c0 + cx x + cy y (gait frame);
    the neutral stance's level with fewer than three stance feet.

    The normal equations D^T D c = D^T z of the design rows D = (1, x, y), as numpy's `@` and
    `linalg.solve` compute them: sums of products by fused multiply-adds in row order (OpenBLAS's
    dsyrk and dgemv), then LU with partial pivoting (its dgetf2: the column scaled by the
    reciprocal of the pivot) and the two triangular solves (dtrsv: the upper one divides)."""
    normal, right = np.zeros((3, 3)), np.zeros(3)
    first = True
    for leg in range(6):
        if stance[leg]:
            row = (1.0, feet[leg, 0], feet[leg, 1])
            for i in range(3):
                for j in range(3):
                    normal[i, j] = row[i] * row[j] if first else fused_multiply_add(row[i], row[j], normal[i, j])
                right[i] = row[i] * feet[leg, 2] if first else fused_multiply_add(row[i], feet[leg, 2], right[i])
            first = False
    if stance.sum() < 3:
        return neutral_height, 0.0, 0.0
    return _solve3(normal, right)


@njit(cache=True)
def _solve3(a, b):
    """x of a x = b for a 3x3 `a` (overwritten with its LU factors) in LAPACK dgesv's steps."""
    pivots = np.zeros(3, np.int64)
    for j in range(3):
        for i in range(j):                      # the earlier row swaps, on this column
            a[i, j], a[pivots[i], j] = a[pivots[i], j], a[i, j]
        if j == 2:                              # forward substitution within the column
            a[1, 2] -= a[1, 0] * a[0, 2]
        for i in range(j, 3):                   # this column less the factors found so far
            if j == 1:
                a[i, 1] -= a[i, 0] * a[0, 1]
            elif j == 2:
                a[i, 2] -= fused_multiply_add(a[i, 1], a[1, 2], a[i, 0] * a[0, 2])
        pivot = j
        for i in range(j + 1, 3):
            if abs(a[i, j]) > abs(a[pivot, j]):
                pivot = i
        pivots[j] = pivot
        for k in range(j + 1):
            a[j, k], a[pivot, k] = a[pivot, k], a[j, k]
        reciprocal = 1.0 / a[j, j]
        for i in range(j + 1, 3):
            a[i, j] *= reciprocal
    x = b.copy()
    for i in range(3):
        x[i], x[pivots[i]] = x[pivots[i]], x[i]
    for i in range(3):                          # unit lower triangle, forward
        for k in range(i + 1, 3):
            x[k] = fused_multiply_add(-x[i], a[k, i], x[k])
    for i in range(2, -1, -1):                  # upper triangle, backward
        x[i] /= a[i, i]
        for k in range(i):
            x[k] = fused_multiply_add(-x[i], a[k, i], x[k])
    return x[0], x[1], x[2]


@njit(cache=True)
def _follow_walk_plane(feet, liftoff, search_floor, offset, rate):
    """Move the gait frame vertically so that the stance feet's plane returns to the neutral
    stance's height under the body (first order, plane_time_constant): on a slope the body
    climbs with the feet, after a step it settles on the new level. Returns the shift."""
    shift = offset * rate
    for leg in range(6):
        feet[leg, 2] -= shift
        liftoff[leg, 2] -= shift
        search_floor[leg] -= shift
    return shift
