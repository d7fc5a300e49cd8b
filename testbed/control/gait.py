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

    @property
    def fewest_feet_down(self) -> int:
        """The fewest legs in stance at any time of the cycle. The most legs swing together at
        some leg's swing start: counted just after it (a millionth of a cycle)."""
        return 6 - max(sum((start + 1e-6 - other + self.duty) % 1.0 >= self.duty for other in self.swing_start)
                       for start in self.swing_start)


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
# m: a swing foot this far above its start that touches something on its way up has met a riser
RISER_HEIGHT = 0.01
# Footholds the front feet stood on, remembered per side (a ring): the ground's slope ahead.
FRONT_LEGS = (0, 5)
FOOTHOLDS = 6
# Where each foot of a side stood at its last lift-offs (a ring, every leg's): the x-neighbours
# around a follower's planned touch-down bracket an edge between them.
STOOD = 12
# m between two footholds whose heights give the ground's local slope (nearer: the same foothold)
FOOTHOLD_SPACING = 0.01
# m a follower's touch-down may move onto a proven foothold beyond the stride's reach allowance
FOOTHOLD_REACH = 0.005
# m a follower's touch-down lies beyond the foothold it aims at, away from the edge: the foot that
# stood there may have stood against the riser (a front foot's swing can end within its radius of
# a step-down edge), where a descending sphere catches the corner (robot.foot_radius, 1 cm)
FOOTHOLD_MARGIN = 0.01
# The ground's slope ahead: a line through each side's last SLOPE_FOOTHOLDS front footholds, trusted
# when they fit it within SLOPE_FIT (RMS; a step among them does not), moving the stance at most
# SLOPE_SHIFT_LIMIT uphill.
SLOPE_FOOTHOLDS = 4
SLOPE_FIT = 0.004
SLOPE_SHIFT_LIMIT = 0.04
# m off the plane of the feet that stood before it: a landing on uneven ground takes its load
# before the legs it relieves lift (TerrainAdaptation.load_time)
UNEVEN_LANDING = 0.005
# The landing reach, the lost-ground wait and the foothold heights (`_at_foothold_heights`) are
# for gaits whose swings leave three feet down or fewer (the tripod): with four or more down
# (ripple, wave) the support holds without any one foot, and on rigid ground their lightly loaded
# feet read no ground for long stretches (docs/control.md, "Structure", item 1).
# m: a swing with terrain adaptation ends this far below the ground it expects, so that the foot,
# lagging its target, still meets level ground within its swing instead of searching for it at
# the gait clock's expense.
LANDING_REACH = 0.004
# s a standing foot's sensor reads no ground before the foot counts as having lost it (a landing
# on rigid ground chatters for a few milliseconds): the legs it would relieve wait meanwhile.
LOST_GROUND_TIME = 0.02


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
    clearance: float = 0.0      # m, a swing clears known higher footholds ahead and a riser by this
    max_swing_height: float = 0.0   # m above the swing's start; 0: the swing height, never raised
    edge_margin: float = 0.0    # m, a foot blocked by a riser lands at least this far beyond it
    max_step_length: float = 0.0    # m, the longest stride the legs reach (a follower's aim at a foothold)
    slope_shift: float = 0.0    # m per unit of the ground's slope under the front feet: touch-downs move uphill
    load_time: float = 0.0      # s a foot landed on uneven ground keeps its contact before a leg lifts; 0: lift at once
    load_preload: float = 0.0   # m such a foot is pressed below where it touched over its load time

    @property
    def follows_terrain(self) -> bool:
        return math.isfinite(self.plane_time_constant)

    @staticmethod
    def confirmation(search_speed: float, search_depth: float) -> "TerrainAdaptation":
        """Touch-down confirmation alone: a swing ends when its foot touches at the end of the
        ellipse, or after reaching down at most `search_depth` for the ground; touches earlier in
        the swing are ignored and the gait frame stays level (this gait knows no terrain)."""
        return TerrainAdaptation(search_speed, search_depth, 1.0, math.inf)

    @property
    def raises_swings(self) -> bool:
        return self.max_swing_height > 0.0


# The gait's constants and its state, each one record (a one-element structured array) that the
# compiled steps read and update by field name. Flags are stored as uint8 (numba's records hold no
# bool arrays); the generator's Python side sees them as bool arrays.
GAIT_PARAMETERS = np.dtype([
    ("period", "f8"),                   # s per cycle
    ("duty", "f8"),                     # stance share of the cycle
    ("lead", "f8"),                     # s, the swing command runs this far ahead of the gait clock
    ("stance_time", "f8"),              # s, duty * period
    ("swing_height", "f8"),             # m
    ("neutral_height", "f8"),           # m, mean height of the start stance's feet
    ("search_speed", "f8"),             # TerrainAdaptation's fields
    ("search_depth", "f8"),
    ("touchdown_phase", "f8"),
    ("plane_time_constant", "f8"),
    ("clearance", "f8"),
    ("max_swing_height", "f8"),
    ("edge_margin", "f8"),
    ("max_step_length", "f8"),          # m, the longest stride the legs reach
    ("slope_shift", "f8"),              # m per unit slope, touch-downs move uphill
    ("load_time", "f8"),                # s a landed foot keeps its contact before a leg lifts
    ("load_preload", "f8"),             # m it is pressed below where it touched meanwhile
    ("on_three_feet", "u1"),            # the pattern's swings leave three feet down or fewer
    ("swing_start", "f8", 6),           # per leg, fraction of the cycle at which its swing starts
    ("neutral", "f8", (6, 3)),          # the start stance, body frame
])
GAIT_STATE = np.dtype([
    ("feet", "f8", (6, 3)),             # current foot targets, body frame
    ("liftoff", "f8", (6, 3)),          # where each swing began
    ("search_floor", "f8", 6),          # m, lowest a swing foot reaches down for ground
    ("lift", "f8", 6),                  # m, height of each leg's current swing
    ("loading", "f8", 6),               # s each landed foot still has to hold its contact; 0: loaded
    ("pressed", "f8", 6),               # m each landed foot's target lies below where it touched
    ("ungrounded", "f8", 6),            # s each standing foot's sensor has read no ground
    ("raised", "f8", 6),                # m, extra height for a leg's next swing after a blocked one
    ("edge", "f8", (6, 2)),             # (x, z) of a riser a swing foot met, gait frame; x NaN: none
    ("footholds", "f8", (2, FOOTHOLDS, 3)),   # per side (left, right): where its front foot stood at its
                                        # last lift-offs, gait frame, moving with the ground; x NaN: none
    ("foothold_count", "i8", 2),        # lift-offs recorded per side
    ("stood", "f8", (2, STOOD, 3)),     # per side: where any of its feet stood at its last lift-offs,
                                        # gait frame, moving with the ground; x NaN: none
    ("stood_count", "i8", 2),           # lift-offs recorded per side in `stood`
    ("aim", "i8", 6),                   # the `stood` slot a middle or rear swing lands at; -1: none
    ("aim_offset", "f8", 6),            # m along x from that foothold to the touch-down; 0: on it
    ("swinging", "u1", 6),              # in the air
    ("scheduled", "u1", 6),             # the schedule's swings at the last step
    ("searching", "u1", 6),             # reaching down for ground the clock waits for
    ("landing", "u1", 6),               # swinging past the rising half or the scheduled end: a touch lands
    ("stopping", "u1"),                 # no new swings
])


class GaitGenerator:
    """The gait's state lives in a record that one compiled function per tick updates in place
    (`_adaptive_step`, `_blind_step`)."""

    def __init__(self, name: str, neutral: np.ndarray, period: float, swing_height: float,
                 adaptation: TerrainAdaptation | None = None, lead: float = 0.0):
        self.name = name
        self.lead = lead            # s, the swing command runs this far ahead of the gait clock
        self.adaptation = adaptation
        self.waited = 0.0           # s the gait clock stood still for feet searching the ground
        self.frame_drop = 0.0       # m the ground has moved down in the gait frame (walk-plane following)
        self.neutral = np.asarray(neutral, dtype=float)
        self.neutral_height = float(self.neutral[:, 2].mean())
        self.period = period
        self.swing_height = swing_height
        self.pattern = pattern = GAITS.resolve(name)
        self.duty, self.swing_start = pattern.duty, np.asarray(pattern.swing_start, dtype=float)
        search = adaptation or TerrainAdaptation(0.0, 0.0, 1.0, math.inf)
        self.raises_swings = search.raises_swings
        self.parameters = np.zeros(1, GAIT_PARAMETERS)
        for field, value in (("period", period), ("duty", self.duty), ("lead", lead),
                             ("stance_time", self.stance_time), ("swing_height", swing_height),
                             ("neutral_height", self.neutral_height), ("search_speed", search.search_speed),
                             ("search_depth", search.search_depth), ("touchdown_phase", search.touchdown_phase),
                             ("plane_time_constant", search.plane_time_constant),
                             ("clearance", search.clearance), ("max_swing_height", search.max_swing_height),
                             ("edge_margin", search.edge_margin), ("max_step_length", search.max_step_length),
                             ("slope_shift", search.slope_shift), ("load_time", search.load_time),
                             ("load_preload", search.load_preload),
                             ("on_three_feet", pattern.fewest_feet_down <= 3),
                             ("swing_start", self.swing_start), ("neutral", self.neutral)):
            self.parameters[field] = value
        self.state_record = record = np.zeros(1, GAIT_STATE)
        record["feet"], record["liftoff"], record["search_floor"] = self.neutral, self.neutral, -np.inf
        record["lift"], record["edge"], record["aim"] = swing_height, np.nan, -1
        record["footholds"], record["stood"] = np.nan, np.nan
        self.state = GaitState(record["feet"][0], record["swinging"][0].view(bool), record["liftoff"][0])
        self.scheduled = record["scheduled"][0].view(bool)
        self.search_floor = record["search_floor"][0]
        self.searching = record["searching"][0].view(bool)
        self._stepped_phase = (math.nan, np.zeros(6))     # (gait time, phase) of the last step

    @property
    def stance_time(self) -> float:
        return self.duty * self.period

    @property
    def stopping(self) -> bool:
        return bool(self.state_record["stopping"][0])

    def phase(self, t: float) -> np.ndarray:
        """(6,) phase of each leg in [0, 1): stance below the duty factor, swing above. At the
        last step's gait time, that step's array (never written again: a new one per step)."""
        stepped_time, stepped_phase = self._stepped_phase
        if t == stepped_time:
            return stepped_phase
        return _phase(t, self.parameters, np.empty(6))

    def scheduled_swing(self, t: float) -> np.ndarray:
        if not self.pattern.walks:
            return np.zeros(6, bool)
        return self.phase(t) >= self.duty

    def swing_progress(self, t: float) -> np.ndarray:
        return _progress(self.phase(t), self.parameters, np.empty(6))


    def stop(self) -> None:
        """Finish the swings under way, then keep every foot down."""
        self.state_record["stopping"] = True

    def rotate(self, rotation: np.ndarray) -> None:
        """Turn the gait frame's contents (targets, swing starts, search floors) by `rotation`
        (3, 3) about the frame's origin: the frame itself turns by its transpose."""
        rotate_frame(self.state_record, rotation)

    def clock(self, t: float) -> float:
        """Gait time at run time t: the time spent waiting for the ground does not count."""
        return t - self.waited

    def step(self, t: float, dt: float, command: Twist, contact: np.ndarray | None = None,
             measured: np.ndarray | None = None) -> np.ndarray:
        """Advance to time t; returns (6, 3) foot targets in the body frame. Touch-down confirmation
        and terrain adaptation use `contact` (the foot sensors) and `measured`, the feet where the
        joint encoders put them (gait frame): a foot lands where it touched, not where its lagging
        target had got to. Without `contact` the gait follows its schedule blindly."""
        twist, phase = (command.vx, command.vy, command.wz), np.empty(6)
        if self.adaptation is None or contact is None:
            _blind_step(t, dt, twist, self.pattern.walks, self.parameters, self.state_record, phase)
            self._stepped_phase = (t, phase)
            return self.state.feet.copy()
        gait_time = self.clock(t)
        searched, plane_shift = _adaptive_step(gait_time, dt, twist, np.asarray(contact, dtype=bool), measured,
                                               self.parameters, self.state_record, phase)
        self._stepped_phase = (gait_time, phase)
        if searched:
            self.waited += dt           # the clock waits: no leg lifts, the body does not move
        elif self.adaptation.follows_terrain:
            self.frame_drop += plane_shift
        return self.state.feet.copy()


# ------------------------------------------------------------------ compiled steps
# One call per tick with the gait's records, updated in place.

@njit(cache=True)
def _phase(t, parameters, out):
    """(6,) phase of each leg at gait time t, into `out`."""
    p = parameters[0]
    for leg in range(6):
        # Rounded to 1e-9 of a cycle so that legs whose swings meet end-to-end never overlap for a
        # tick through floating-point error at the boundary.
        out[leg] = (np.rint((t / p.period - p.swing_start[leg] + p.duty) * 1e9) / 1e9) % 1.0
    return out


@njit(cache=True)
def _progress(phase, parameters, out):
    """Where each swing's command is on its ellipse: the phase's share of the swing plus the
    lead, so that the lagging servos put the foot itself on the ellipse about on schedule and
    on the ground by the scheduled touch-down; the command then waits at the touch-down point."""
    p = parameters[0]
    ahead = p.lead / ((1.0 - p.duty) * p.period)
    for leg in range(6):
        share = (phase[leg] - p.duty) / (1.0 - p.duty) + ahead
        share = share if share > 0.0 else 0.0
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
def _touchdown(parameters, twist):
    """Half a step ahead of the neutral point, for the current command (vx, vy, wz)."""
    p = parameters[0]
    vx, vy, wz = twist
    return p.neutral + 0.5 * p.stance_time * _foot_velocity(p.neutral, vx, vy, wz)


@njit(cache=True)
def _move_stance(feet, stance, twist, dt):
    # A stance foot is fixed on the ground: in the body frame it moves against the body twist.
    vx, vy, wz = twist
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
def _move_swing(feet, liftoff, progress, swing, touchdown, lift):
    """The swing feet along their ellipses; `lift` (6,): each swing's height."""
    for leg in range(6):
        if swing[leg]:
            blend = _swing_blend(progress[leg])
            for axis in range(3):
                feet[leg, axis] = liftoff[leg, axis] + (touchdown[leg, axis] - liftoff[leg, axis]) * blend
            feet[leg, 2] += lift[leg] * math.sin(math.pi * progress[leg])


@njit(cache=True)
def _blind_step(t, dt, twist, walking, parameters, state, phase):
    """The gait on its schedule alone: no foot sensors, no terrain. `twist`: (vx, vy, wz);
    `parameters`, `state`: the GAIT_PARAMETERS and GAIT_STATE records; `phase` receives the legs'
    phases."""
    p, s = parameters[0], state[0]
    feet, liftoff = s.feet, s.liftoff
    swinging = s.swinging != 0
    _phase(t, parameters, phase)
    swing = phase >= p.duty
    if not walking:
        swing[:] = False
    if s.stopping:
        swing &= swinging       # no new swings; running ones finish
    touchdown = _touchdown(parameters, twist)
    for leg in range(6):
        if swing[leg] and not swinging[leg]:
            liftoff[leg] = feet[leg]
        elif swinging[leg] and not swing[leg]:
            # The last swing tick falls just short of u = 1: a landing foot ends its ellipse first.
            feet[leg] = touchdown[leg]
    _move_stance(feet, ~swing, twist, dt)
    if swing.any():
        _move_swing(feet, liftoff, _progress(phase, parameters, np.empty(6)), swing, touchdown, s.lift)
    _store_flags(s.swinging, swing)


@njit(cache=True)
def _store_flags(target, flags):
    for leg in range(6):
        target[leg] = 1 if flags[leg] else 0


@njit(cache=True)
def _adaptive_step(t, dt, twist, contact, measured, parameters, state, phase):
    """The gait with touch-down confirmation and terrain adaptation, at gait time t. `twist`:
    (vx, vy, wz); `contact`: the foot sensors; `measured`: the feet where the encoders put them
    (gait frame), or None; `parameters`, `state`: the GAIT_PARAMETERS and GAIT_STATE records;
    `phase` receives the legs' phases. Returns (whether feet searched the ground, so that the
    clock waited; the gait frame's vertical shift)."""
    p, s = parameters[0], state[0]
    feet, liftoff, search_floor = s.feet, s.liftoff, s.search_floor
    swinging, scheduled = s.swinging != 0, s.scheduled != 0
    follows_terrain = math.isfinite(p.plane_time_constant)
    _phase(t, parameters, phase)
    now = phase >= p.duty
    if s.stopping:
        now &= scheduled | swinging
    lifting = now & ~scheduled
    progress = _progress(phase, parameters, np.empty(6))
    # Ground found in the second part of a swing, or at or after its scheduled end: land there.
    touched = swinging & contact & (~now | (progress >= p.touchdown_phase))
    raises = p.max_swing_height > 0.0
    if raises and measured is not None and (touched & now).any():
        touched &= ~_short_of_edges(parameters, s, touched & now, measured, ~swinging)
    if measured is not None:
        _copy_rows(feet, measured, touched)     # where it touched, not where its lagging target got to
    elif not follows_terrain:
        _copy_rows(feet, _touchdown(parameters, twist), touched)     # the ellipse's end
    swinging &= ~touched
    if raises:
        _remember_landings(s, touched)
    if p.load_time > 0.0:
        uneven = _off_the_stance_plane(feet, touched, swinging, p.neutral_height)
        # back in the air: on its ellipse again if its swing's time is not up, else searching
        swinging |= _slid_off(p.load_time, s.loading, touched & uneven, contact, swinging, dt)
        _press_loading(feet, s.loading, s.pressed, swinging, p.load_preload, p.load_preload * dt / p.load_time)
    unsure = False      # a foot that would carry the body reads no ground, not yet for long
    on_three_feet = follows_terrain and p.on_three_feet != 0
    if on_three_feet:
        _time_ungrounded(s.ungrounded, swinging, contact, dt)
        if lifting.any():
            lost, unsure = _lost_ground(feet, search_floor, swinging | lifting, s.ungrounded)
            swinging |= lost
    searching = swinging & ~now
    _store_flags(s.searching, searching)
    _store_flags(s.landing, swinging & (~now | (progress >= RISING_HALF)))
    if searching.any():
        _search(feet, swinging, searching, search_floor, p.search_speed * dt)
        if raises:
            _remember_landings(s, searching & ~swinging)     # down at the bottom of the search
        _store_flags(s.swinging, swinging)
        return True, 0.0
    if lifting.any() and (unsure or _still_loading(s.loading, swinging, lifting)):
        _store_flags(s.swinging, swinging)
        return True, 0.0
    _copy_rows(liftoff, feet, lifting)
    slope = 0.0     # dz/dx under the front feet (`footholds_slope`)
    if raises:
        _plan_lifts(parameters, s, lifting, ~swinging)
        if measured is None:
            _record_footholds(s, lifting, feet)
        else:
            _record_footholds(s, lifting, measured)
        slope = footholds_slope(s.footholds, s.foothold_count)
        _choose_footholds(parameters, s, lifting, twist, slope)
    swinging |= lifting
    _store_flags(s.swinging, swinging)
    _store_flags(s.scheduled, now)
    touchdown = _touchdown(parameters, twist)
    if raises:
        _onto_footholds(s, touchdown, swinging)
        _shift_uphill(p.slope_shift * slope, touchdown, s.aim, swinging)
        _beyond_edges(parameters, s, touchdown)
    plane_height = 0.0
    if follows_terrain:
        plane_height, slope_x, slope_y = walk_plane(feet, ~swinging, p.neutral_height)
        for leg in range(6):
            touchdown[leg, 2] = plane_height + touchdown[leg, 0] * slope_x + touchdown[leg, 1] * slope_y
        if on_three_feet:
            if raises:
                _at_foothold_heights(s, touchdown, swinging)
            touchdown[:, 2] -= LANDING_REACH
    _move_stance(feet, ~swinging, twist, dt)
    if raises:
        _move_edges(s.edge, twist, feet, dt)
        _move_footholds(s.footholds, twist, dt)
        _move_footholds(s.stood, twist, dt)
    if not follows_terrain:
        _settle_stance(feet, swinging, p.neutral, dt)
    in_swing = swinging & now
    blocked = in_swing & contact & (progress < RISING_HALF)
    if blocked.any() and measured is None:
        _hold_blocked(liftoff, blocked, progress, touchdown, feet, twist, dt)
    elif blocked.any():
        _hold_blocked(liftoff, blocked, progress, touchdown, measured, twist, dt)
        if raises:
            _lift_over(parameters, s, blocked, measured)
    _move_swing(feet, liftoff, progress, in_swing, touchdown, s.lift)
    if raises and measured is None:
        _keep_over_edges(parameters, s, in_swing, feet)
    elif raises:
        _keep_over_edges(parameters, s, in_swing, measured)
    for leg in range(6):
        if swinging[leg]:
            search_floor[leg] = touchdown[leg, 2] - p.search_depth
    if not follows_terrain:
        return False, 0.0
    shift = _follow_walk_plane(feet, liftoff, search_floor, plane_height - p.neutral_height,
                               min(1.0, dt / p.plane_time_constant))
    for leg in range(6):
        s.edge[leg, 1] -= shift
    s.footholds[:, :, 2] -= shift
    s.stood[:, :, 2] -= shift
    return False, shift


@njit(cache=True)
def _off_the_stance_plane(feet, touched, swinging, neutral_height):
    """The feet among `touched` that landed more than UNEVEN_LANDING above or below the plane of
    the feet that stood before them: on a block, a step, a stair or past a ramp's gradient
    change, where a foot can stand on an edge's corner. On even ground none."""
    uneven = np.zeros(6, dtype=np.bool_)
    stood = ~swinging & ~touched
    if not touched.any() or stood.sum() < 3:
        return uneven
    plane_height, slope_x, slope_y = walk_plane(feet, stood, neutral_height)
    for leg in range(6):
        if touched[leg]:
            ground = plane_height + slope_x * feet[leg, 0] + slope_y * feet[leg, 1]
            uneven[leg] = abs(feet[leg, 2] - ground) > UNEVEN_LANDING
    return uneven


@njit(cache=True)
def _time_ungrounded(ungrounded, swinging, contact, dt):
    for leg in range(6):
        ungrounded[leg] = ungrounded[leg] + dt if not swinging[leg] and not contact[leg] else 0.0


@njit(cache=True)
def _lost_ground(feet, search_floor, moving, ungrounded):
    """The feet that will carry the body when the legs `moving` lift, and whose sensors have read
    no ground for LOST_GROUND_TIME (one landed on a corner that gave way, or its sensor caught a
    block's side for a moment): they search for ground again first, unless already at the bottom
    of their search. And whether another of them reads no ground, not yet for that long."""
    lost = np.zeros(6, dtype=np.bool_)
    unsure = False
    for leg in range(6):
        if moving[leg] or ungrounded[leg] == 0.0 or feet[leg, 2] <= search_floor[leg]:
            continue
        lost[leg] = ungrounded[leg] >= LOST_GROUND_TIME
        unsure |= not lost[leg]
    return lost, unsure


@njit(cache=True)
def _slid_off(load_time, loading, touched, contact, swinging, dt):
    """Load transfer: a foot that lands holds its contact for `load_time` (s) while the legs it
    relieves still stand (`_still_loading`: where their lift would leave three feet down),
    taking its share of the weight. One that loses its
    contact meanwhile has slid off an edge or a block's corner as it took weight: the legs that
    lifted now would have left the body on too few feet. Returns those feet, to search for
    ground again."""
    slid = np.zeros(6, dtype=np.bool_)
    for leg in range(6):
        if touched[leg]:
            loading[leg] = load_time
        elif loading[leg] > 0.0 and not swinging[leg]:
            slid[leg] = not contact[leg]
            loading[leg] = 0.0 if slid[leg] else max(0.0, loading[leg] - dt)
    return slid


@njit(cache=True)
def _press_loading(feet, loading, pressed, swinging, preload, depth):
    """Lower each foot still taking its load by `depth` (m) a tick, down to `preload` below
    where it touched: pressed into the ground, it carries weight while the legs it relieves still
    stand, and on an edge's corner it slides off now. A loaded foot rises back as fast."""
    for leg in range(6):
        if swinging[leg]:
            pressed[leg] = 0.0
            continue
        wanted = preload if loading[leg] > 0.0 else 0.0
        step = min(max(wanted - pressed[leg], -depth), depth)
        feet[leg, 2] -= step
        pressed[leg] += step


@njit(cache=True)
def _still_loading(loading, swinging, lifting):
    """Whether a landed foot is still taking its load while the legs about to lift would leave
    the body on three feet or fewer (the tripod's): with four or more down (ripple, wave) one
    foot that slides off leaves a support that holds."""
    if (~swinging & ~lifting).sum() > 3:
        return False
    for leg in range(6):
        if loading[leg] > 0.0 and not swinging[leg]:
            return True
    return False


@njit(cache=True)
def _remember_landings(s, touched):
    """A foot that landed forgets its riser and its aim; a swing that was never blocked clears
    the extra height the leg's next swing would have had."""
    for leg in range(6):
        if touched[leg]:
            s.aim[leg] = -1
            if math.isnan(s.edge[leg, 0]):
                s.raised[leg] = 0.0
            s.edge[leg, 0] = np.nan


@njit(cache=True)
def _plan_lifts(parameters, s, lifting, stance):
    """The height of each new swing: the swing height, raised to clear by `clearance` the
    highest stance foothold ahead of it on its side of the body (a rear foot follows the front
    feet onto a step) and by what the leg's last blocked swing needed; at most max_swing_height."""
    p = parameters[0]
    feet = s.feet
    for leg in range(6):
        if not lifting[leg]:
            continue
        needed = p.swing_height + s.raised[leg]
        for other in range(6):
            if stance[other] and other != leg and feet[other, 1] * feet[leg, 1] > 0.0 \
                    and feet[other, 0] > feet[leg, 0]:
                needed = max(needed, feet[other, 2] - feet[leg, 2] + p.clearance)
        s.lift[leg] = min(needed, p.max_swing_height)


@njit(cache=True)
def _short_of_edges(parameters, s, touched, measured, stance):
    """The swing feet among `touched` that touched ground on their way down higher than both
    the stance feet's plane and their swing's start by more than RISER_HEIGHT (a step's top, met
    from above), or, aimed at a foothold lower than their start by more than RISER_HEIGHT, within
    RISER_HEIGHT of their start's height and short of that foothold (the upper tread's corner, met
    on the way down a step: the foot that stood there stood at least its radius beyond the edge),
    or short of a riser they met: they do not land yet. The first such touch is
    remembered as an edge, so that the foot keeps clear above it and lands `edge_margin` beyond
    it, not on the corner it may have met; a later touch short of it, higher than the edge, raises
    the edge to where the foot is (a riser met on the way down: elevator reflex)."""
    p = parameters[0]
    short = np.zeros(6, dtype=np.bool_)
    plane_height, slope_x, slope_y = walk_plane(s.feet, stance, p.neutral_height)
    for leg in range(6):
        if not touched[leg]:
            continue
        x, y, z = measured[leg, 0], measured[leg, 1], measured[leg, 2]
        ground = max(plane_height + slope_x * x + slope_y * y, s.liftoff[leg, 2])
        if s.aim[leg] >= 0:
            foothold = s.stood[_side(leg), s.aim[leg]]
            aimed = foothold[2]
            if aimed < s.liftoff[leg, 2] - RISER_HEIGHT and abs(z - s.liftoff[leg, 2]) < RISER_HEIGHT \
                    and x < foothold[0]:
                ground = aimed
        if math.isnan(s.edge[leg, 0]):
            if z - ground > RISER_HEIGHT:
                s.edge[leg, 0], s.edge[leg, 1] = x, z
        elif x < s.edge[leg, 0] + p.edge_margin:
            s.edge[leg, 1] = max(s.edge[leg, 1], z)
        short[leg] = x < s.edge[leg, 0] + p.edge_margin
    return short


@njit(cache=True)
def footholds_slope(footholds, count):
    """dz/dx of the ground under the front feet: the least-squares slope of the last
    SLOPE_FOOTHOLDS footholds of each side (one slope, an intercept per side), or 0 when there
    are fewer or they do not lie on it within SLOPE_FIT (RMS): an edge among them."""
    if min(count[0], count[1]) < SLOPE_FOOTHOLDS:
        return 0.0
    means = np.zeros((2, 2))
    for side in range(2):
        for back in range(1, SLOPE_FOOTHOLDS + 1):
            point = footholds[side, (count[side] - back) % FOOTHOLDS]
            means[side, 0] += point[0] / SLOPE_FOOTHOLDS
            means[side, 1] += point[2] / SLOPE_FOOTHOLDS
    sxx, sxz = 0.0, 0.0
    for side in range(2):
        for back in range(1, SLOPE_FOOTHOLDS + 1):
            point = footholds[side, (count[side] - back) % FOOTHOLDS]
            sxx += (point[0] - means[side, 0]) ** 2
            sxz += (point[0] - means[side, 0]) * (point[2] - means[side, 1])
    if not sxx > 0.0:
        return 0.0
    slope = sxz / sxx
    residual = 0.0
    for side in range(2):
        for back in range(1, SLOPE_FOOTHOLDS + 1):
            point = footholds[side, (count[side] - back) % FOOTHOLDS]
            residual += (point[2] - means[side, 1] - slope * (point[0] - means[side, 0])) ** 2
    if math.sqrt(residual / (2 * SLOPE_FOOTHOLDS)) > SLOPE_FIT:
        return 0.0
    return slope


@njit(cache=True)
def _shift_uphill(shift, touchdown, aim, swinging):
    """On a slope a level body's downhill legs reach far down at the end of their stride (the
    rear legs walking up, the front legs walking down) and its uphill legs fold: the touch-downs
    move uphill by `shift` (m, along x; at most SLOPE_SHIFT_LIMIT), the stance with them. A
    swing aimed at a proven foothold keeps it."""
    shift = min(max(shift, -SLOPE_SHIFT_LIMIT), SLOPE_SHIFT_LIMIT)
    for leg in range(6):
        if not (swinging[leg] and aim[leg] >= 0):
            touchdown[leg, 0] += shift


@njit(cache=True)
def _side(leg):
    return 0 if leg < 3 else 1


@njit(cache=True)
def _record_footholds(s, lifting, stood):
    """A foot that lifts has stood where it is through its stance: a proven foothold for the
    feet behind it on its side (`stood`); a front foot's also for the ground's slope (`footholds`)."""
    for leg in range(6):
        if not lifting[leg]:
            continue
        side = _side(leg)
        s.stood[side, s.stood_count[side] % STOOD] = stood[leg]
        s.stood_count[side] += 1
        if leg in FRONT_LEGS:
            s.footholds[side, s.foothold_count[side] % FOOTHOLDS] = stood[leg]
            s.foothold_count[side] += 1


@njit(cache=True)
def _choose_footholds(parameters, s, lifting, twist, slope):
    """A middle or rear swing whose planned touch-down lies between two neighbouring footholds of
    its side (the nearest behind and ahead of it where the side's feet stood) with an edge
    between them (`_edge_between`) aims at the nearer of the two, where the ground is known to
    hold: FOOTHOLD_MARGIN beyond it, away from the edge, as far as the legs reach, else the
    reach allowance nearer to it than planned. Not on an edge's corner, from which a foot slides
    off when it takes the weight (docs/control.md, "Footholds"). On an even ramp the swings keep
    their touch-downs, moved uphill (`_shift_uphill`)."""
    p = parameters[0]
    touchdown = _touchdown(parameters, twist)
    swing_time = (1.0 - p.duty) * p.period
    stride = 2.0 * abs(touchdown[0, 0] - p.neutral[0, 0])
    reach = max(0.0, 0.5 * (p.max_step_length - stride)) + FOOTHOLD_REACH
    for leg in range(6):
        if not lifting[leg] or leg in FRONT_LEGS:
            continue
        s.aim[leg] = -1
        stood = s.stood[_side(leg)]
        count = min(s.stood_count[_side(leg)], STOOD)
        planned = touchdown[leg, 0]
        # the footholds nearest the touch-down, where they will be when the swing lands
        behind, behind_x = _nearest_foothold(stood, count, twist, swing_time, planned + 1e-9, -1.0)
        ahead, ahead_x = _nearest_foothold(stood, count, twist, swing_time, planned, 1.0)
        if behind < 0 or ahead < 0 or not _edge_between(stood, count, twist, swing_time, behind, ahead, slope):
            continue
        if ahead_x - planned < planned - behind_x:
            s.aim[leg], s.aim_offset[leg] = ahead, min(ahead_x + FOOTHOLD_MARGIN, planned + reach) - ahead_x
        else:
            s.aim[leg], s.aim_offset[leg] = behind, max(behind_x - FOOTHOLD_MARGIN, planned - reach) - behind_x


@njit(cache=True)
def _nearest_foothold(stood, count, twist, time, x, direction):
    """The slot of the foothold nearest beyond x in `direction` (+1 ahead, -1 behind) where it
    will be in `time`, and that x; -1 and an infinite x when there is none."""
    best, best_distance = -1, np.inf
    for slot in range(count):
        distance = direction * (_landing_x(stood[slot], twist, time) - x)
        if 0.0 < distance < best_distance:
            best, best_distance = slot, distance
    return best, x + direction * best_distance


@njit(cache=True)
def _edge_between(stood, count, twist, time, behind, ahead, slope):
    """Whether the rise from foothold `behind` to foothold `ahead` is an edge: more than
    RISER_HEIGHT beyond what the ground's slope under the front feet (`slope`) explains, and
    beyond what the ground's slope just behind and just ahead of them explains (the next foothold
    at least FOOTHOLD_SPACING further each way; at a ramp's gradient change one of the two
    does). With neither of those known (the first strides) the ground is not judged."""
    behind_x = _landing_x(stood[behind], twist, time)
    ahead_x = _landing_x(stood[ahead], twist, time)
    run, rise = ahead_x - behind_x, stood[ahead, 2] - stood[behind, 2]
    if abs(rise - slope * run) <= RISER_HEIGHT:
        return False
    judged = False
    for end, end_x, direction in ((behind, behind_x, -1.0), (ahead, ahead_x, 1.0)):
        outer, outer_x = _nearest_foothold(stood, count, twist, time, end_x + direction * FOOTHOLD_SPACING, direction)
        if outer < 0:
            continue
        judged = True
        local_slope = (stood[end, 2] - stood[outer, 2]) / (end_x - outer_x)
        if abs(rise - local_slope * run) <= RISER_HEIGHT:
            return False
    return judged


@njit(cache=True)
def _landing_x(point, twist, time):
    velocity_x, _ = _ground_velocity(point[0], point[1], twist[0], twist[1], twist[2])
    return point[0] - velocity_x * time


@njit(cache=True)
def _onto_footholds(s, touchdown, swinging):
    for leg in range(6):
        if swinging[leg] and s.aim[leg] >= 0:
            touchdown[leg, 0] = s.stood[_side(leg), s.aim[leg], 0] + s.aim_offset[leg]


@njit(cache=True)
def _at_foothold_heights(s, touchdown, swinging):
    """A swing aimed at a proven foothold comes down to the height its foot stood at there, not
    to the stance feet's plane: past an edge the plane is the other level's (a stair down, the
    foot would search the rest of the way with the gait clock waiting)."""
    for leg in range(6):
        if swinging[leg] and s.aim[leg] >= 0:
            touchdown[leg, 2] = s.stood[_side(leg), s.aim[leg], 2]


@njit(cache=True)
def _move_footholds(footholds, twist, dt):
    """Footholds are on the ground: they move against the body twist."""
    vx, vy, wz = twist
    for side in range(2):
        for slot in range(footholds.shape[1]):
            velocity_x, velocity_y = _ground_velocity(footholds[side, slot, 0], footholds[side, slot, 1], vx, vy, wz)
            footholds[side, slot, 0] -= velocity_x * dt
            footholds[side, slot, 1] -= velocity_y * dt


@njit(cache=True)
def _lift_over(parameters, s, blocked, measured):
    """A swing foot blocked on its way up (a riser): its swing rises to clear the foot's height
    by `clearance` (at most max_swing_height), the leg's next swing as well, and the riser is
    remembered (its x, and the highest the foot touched it) so that the foot lands beyond it."""
    p = parameters[0]
    for leg in range(6):
        risen = measured[leg, 2] - s.liftoff[leg, 2]
        # a foot still at the height it left is only leaving the ground
        if blocked[leg] and risen > RISER_HEIGHT:
            needed = risen + p.clearance
            s.lift[leg] = min(max(s.lift[leg], needed), p.max_swing_height)
            s.raised[leg] = max(s.raised[leg], s.lift[leg] - p.swing_height)
            if math.isnan(s.edge[leg, 0]):
                s.edge[leg, 0], s.edge[leg, 1] = measured[leg, 0], measured[leg, 2]
            s.edge[leg, 0] = max(s.edge[leg, 0], measured[leg, 0])
            s.edge[leg, 1] = max(s.edge[leg, 1], measured[leg, 2])


@njit(cache=True)
def _move_edges(edge, twist, feet, dt):
    """Remembered risers are on the ground: they move against the body twist like stance feet."""
    vx, vy, wz = twist
    for leg in range(6):
        if not math.isnan(edge[leg, 0]):
            velocity_x, _ = _ground_velocity(edge[leg, 0], feet[leg, 1], vx, vy, wz)
            edge[leg, 0] -= velocity_x * dt


@njit(cache=True)
def _beyond_edges(parameters, s, touchdown):
    """A foot that met a riser lands at least edge_margin beyond it (not on its corner), at most
    edge_margin further than its planned touch-down."""
    p = parameters[0]
    for leg in range(6):
        if not math.isnan(s.edge[leg, 0]):
            planned = touchdown[leg, 0]
            touchdown[leg, 0] = min(max(planned, s.edge[leg, 0] + p.edge_margin), planned + p.edge_margin)


@njit(cache=True)
def _keep_over_edges(parameters, s, in_swing, measured):
    """A swing foot short of the riser it met stays `clearance` above the highest point where it
    touched it, so that it does not come down on the corner; while the foot itself (`measured`)
    is still lower than that by more than RISER_HEIGHT it holds its place over the ground short of
    the riser instead of pushing into its face."""
    p = parameters[0]
    for leg in range(6):
        if in_swing[leg] and not math.isnan(s.edge[leg, 0]) and s.feet[leg, 0] < s.edge[leg, 0] + p.edge_margin:
            top = s.edge[leg, 1] + p.clearance
            s.feet[leg, 2] = max(s.feet[leg, 2], top)
            if measured[leg, 2] < top - RISER_HEIGHT:
                s.feet[leg, 0] = min(s.feet[leg, 0], s.edge[leg, 0])


@njit(cache=True)
def rotate_frame(state, rotation):
    """GaitGenerator.rotate on a GAIT_STATE record: rows p -> rotation p of the targets and swing
    starts; each search floor moves with its foot's height."""
    s = state[0]
    feet, liftoff, search_floor = s.feet, s.liftoff, s.search_floor
    for leg in range(6):
        before = feet[leg, 2]
        _rotate_row(feet, leg, rotation)
        _rotate_row(liftoff, leg, rotation)
        search_floor[leg] += feet[leg, 2] - before
    for side in range(2):
        for slot in range(FOOTHOLDS):
            _rotate_row(s.footholds[side], slot, rotation)
        for slot in range(STOOD):
            _rotate_row(s.stood[side], slot, rotation)


@njit(cache=True)
def _rotate_row(points, row, rotation):
    x, y, z = points[row, 0], points[row, 1], points[row, 2]
    for axis in range(3):
        points[row, axis] = rotation[axis, 0] * x + rotation[axis, 1] * y + rotation[axis, 2] * z


@njit(cache=True)
def _copy_rows(target, source, rows):
    for leg in range(6):
        if rows[leg]:
            target[leg] = source[leg]


@njit(cache=True)
def _hold_blocked(liftoff, blocked, progress, touchdown, feet, twist, dt):
    """Elevator reflex (Cruse's Walknet): a swing foot that meets something while it rises, such
    as a step's riser, stops moving forward over the ground where it is (`feet`: the encoders')
    and keeps rising until it is clear, instead of pushing into the obstacle and being dragged
    up it. The swing's start is moved so that the rest of the ellipse begins where the foot is
    held: once clear, it goes on to its touch-down point without a jump."""
    vx, vy, wz = twist
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
            keep = lowered >= search_floor[leg] or math.isnan(lowered)
            feet[leg, 2] = lowered if keep else search_floor[leg]
            if feet[leg, 2] <= search_floor[leg]:
                swinging[leg] = False


@njit(cache=True)
def walk_plane(feet, stance, neutral_height):
    """(c0, cx, cy) of the stance feet's least-squares plane z = c0 + cx x + cy y (gait frame);
    the neutral stance's level with fewer than three stance feet. The normal equations
    D^T D c = D^T z of the design rows D = (1, x, y), solved by Cramer's rule."""
    if stance.sum() < 3:
        return neutral_height, 0.0, 0.0
    normal, right = np.zeros((3, 3)), np.zeros(3)
    for leg in range(6):
        if stance[leg]:
            row = (1.0, feet[leg, 0], feet[leg, 1])
            for i in range(3):
                for j in range(3):
                    normal[i, j] += row[i] * row[j]
                right[i] += row[i] * feet[leg, 2]
    return _solve3(normal, right)


@njit(cache=True)
def _determinant3(a):
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
            - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@njit(cache=True)
def _solve3(a, b):
    """x of a x = b for a 3x3 `a` (Cramer's rule)."""
    determinant = _determinant3(a)
    x = np.empty(3)
    for column in range(3):
        replaced = a.copy()
        replaced[:, column] = b
        x[column] = _determinant3(replaced) / determinant
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
