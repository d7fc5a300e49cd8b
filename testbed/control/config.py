"""Onboard control's config sections: `[gait]` and `[posture]`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from testbed.control.posture import POSTURE_LAWS
from testbed.control.startup import CalibrationPoses
from testbed.model.validation import finite, non_negative, positive, require

MAX_TARGET_M = 1000.0       # m, farther than a run of a day's walking reaches

@dataclass(frozen=True)
class GaitConfig:
    speed: float
    lateral_speed: float
    turn_rate: float
    target: tuple[float, ...]
    target_tolerance: float
    end_at_arrival: bool
    cruise_turn_rate: float
    heading_gain: float
    swing_height: float
    touchdown_search_speed: float
    touchdown_search_depth: float
    max_step_length: float
    tripod_period: float
    ripple_period: float
    wave_period: float
    still_time: float
    start_ramp: float
    calibration_tilt_deg: float
    calibration_rate_dps: float
    calibration_hold_time: float
    level_hold_time: float | str     # s, or "auto" (testbed/control/startup.py, level_hold)

    def __post_init__(self) -> None:
        finite("gait speeds", self.speed, self.lateral_speed, self.turn_rate)
        require(abs(self.speed) <= 0.5 and abs(self.lateral_speed) <= 0.5,
                 f"gait speeds must lie within +-0.5 m/s, got {self.speed}, {self.lateral_speed}")
        require(abs(self.turn_rate) <= 2.0, f"gait.turn_rate must lie within +-2 rad/s, got {self.turn_rate}")
        require(len(self.target) in (0, 2), "gait.target must be [] or [x, y]")
        finite("gait.target", *self.target)
        require(all(abs(value) <= MAX_TARGET_M for value in self.target),
                f"gait.target must lie within {MAX_TARGET_M:g} m of the start, got {list(self.target)}")
        positive("gait.target_tolerance", self.target_tolerance)
        require(self.target or not self.end_at_arrival, "gait.end_at_arrival needs a gait.target to arrive at")
        positive("gait touch-down search", self.touchdown_search_speed, self.touchdown_search_depth)
        positive("gait timing", self.cruise_turn_rate, self.heading_gain, self.swing_height,
                         self.max_step_length, self.tripod_period, self.ripple_period, self.wave_period)
        require(math.isfinite(self.start_ramp) and self.start_ramp >= 0, "gait.start_ramp must be >= 0")
        require(math.isfinite(self.still_time) and 0.05 <= self.still_time <= 10,
                 f"gait.still_time must lie in [0.05, 10] s, got {self.still_time}")
        require(math.isfinite(self.calibration_tilt_deg) and 0 <= self.calibration_tilt_deg <= 20,
                 f"gait.calibration_tilt_deg must lie in [0, 20], got {self.calibration_tilt_deg}")
        positive("gait calibration timing", self.calibration_rate_dps, self.calibration_hold_time)
        if isinstance(self.level_hold_time, str):
            require(self.level_hold_time == "auto",
                     f"gait.level_hold_time must be a number of seconds or \"auto\", got {self.level_hold_time!r}")
        else:
            positive("gait.level_hold_time (the calibration's level hold)", self.level_hold_time)

    def startup_time(self, duration: float) -> float:
        """s from the start to the first step in a run of `duration` (s): standing still, the
        calibration poses, then the level hold."""
        return CalibrationPoses.from_gait(self, duration).end

    def duration_to_walk(self, walking: float) -> float:
        """s of a run whose start-up leaves `walking` s: the fixed point of duration = start-up +
        walking (an "auto" level hold grows by at most 0.32 s per second of run, where it reaches its
        cap, so each substitution shrinks the error at least that much; they stop within a
        picosecond)."""
        duration, previous = walking + self.startup_time(walking), math.inf
        while abs(duration - previous) > 1e-12:
            duration, previous = walking + self.startup_time(duration), duration
        return duration

    def period(self, gait: str, default: float = 1.0) -> float:
        """s per cycle of the named gait: the `<gait>_period` key, else `default` (the gait's own)."""
        return {"tripod": self.tripod_period, "ripple": self.ripple_period, "wave": self.wave_period}.get(gait, default)

@dataclass(frozen=True)
class PostureConfig:
    """The posture law, the built-in law's gains and limits, and the gait's terrain adaptation (docs/control.md)."""
    law: str                # a registered posture law (`pi`) or MODULE:CLASS
    tilt_kp: float
    tilt_ki: float
    tilt_large_error_deg: float
    tilt_large_kp: float
    height_kp: float
    height_ki: float
    max_tilt_correction_deg: float
    max_height_correction: float
    walk_plane_time_constant: float
    gait_level_time_constant: float
    search_speed: float
    search_depth: float
    touchdown_phase: float
    load_time: float
    load_preload: float
    max_swing_height: float
    step_clearance: float
    edge_margin: float
    slope_stance_shift: float
    reach_margin: float
    max_crouch: float
    crouch_time_constant: float

    def __post_init__(self) -> None:
        POSTURE_LAWS.check_spec(self.law)
        non_negative("posture gains", self.tilt_kp, self.tilt_ki, self.tilt_large_kp, self.height_kp, self.height_ki)
        require(0 <= self.tilt_large_error_deg < self.max_tilt_correction_deg,
                f"posture.tilt_large_error_deg must lie in [0, max_tilt_correction_deg), got {self.tilt_large_error_deg}")
        require(0 < self.max_tilt_correction_deg <= 30,
                 f"posture.max_tilt_correction_deg must lie in (0, 30], got {self.max_tilt_correction_deg}")
        require(0 < self.max_height_correction <= 0.08,
                 f"posture.max_height_correction must lie in (0, 0.08] m, got {self.max_height_correction}")
        positive("posture timing", self.walk_plane_time_constant, self.gait_level_time_constant, self.search_speed)
        require(0 < self.search_depth <= 0.1, f"posture.search_depth must lie in (0, 0.1] m, got {self.search_depth}")
        require(0 < self.touchdown_phase < 1, f"posture.touchdown_phase must lie in (0, 1), got {self.touchdown_phase}")
        require(0 <= self.load_time <= 0.5, f"posture.load_time must lie in [0, 0.5] s, got {self.load_time}")
        require(0 <= self.load_preload <= 0.01, f"posture.load_preload must lie in [0, 0.01] m, got {self.load_preload}")
        non_negative("posture step adaptation", self.max_swing_height, self.step_clearance, self.edge_margin)
        require(0 <= self.slope_stance_shift <= 0.2,
                f"posture.slope_stance_shift must lie in [0, 0.2] m, got {self.slope_stance_shift}")
        require(0 <= self.reach_margin <= 0.05, f"posture.reach_margin must lie in [0, 0.05] m, got {self.reach_margin}")
        require(0 <= self.max_crouch <= 0.05, f"posture.max_crouch must lie in [0, 0.05] m, got {self.max_crouch}")
        positive("posture.crouch_time_constant", self.crouch_time_constant)
        require(self.max_swing_height == 0 or self.max_swing_height >= self.step_clearance,
                 "posture.max_swing_height must be 0 (swings never raised) or at least posture.step_clearance")

    def climb_limits(self, swing_height: float) -> ClimbLimits:
        """What the pilot's feet can clear and reach: the highest step (the highest swing less the
        clearance), the deepest (the search for ground), and the largest rough-ground amplitude
        (from the lowest block to the highest within the highest swing, and down within the search)."""
        highest = max(self.max_swing_height, swing_height)
        return ClimbLimits(highest - self.step_clearance, self.search_depth, min(highest / 2.0, self.search_depth))


class ClimbLimits(NamedTuple):
    up: float                  # m, the highest step up
    down: float                # m, the deepest step down
    rough_amplitude: float     # m, the largest +- amplitude of rough ground
