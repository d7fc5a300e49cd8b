"""Per-run metrics, accumulated tick by tick from ground truth in bounded memory, written as JSON.

Keys are floats in SI units except where the key says `_deg`; null where a metric does not apply.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scipy.spatial.transform import Rotation

from estimators.scoring import METRIC_KEYS, StreamingScore, contact_planes
from testbed.runtime.config import Config
from testbed.runtime.recording import Tick
from testbed.world.stability import feet_on_ground
from testbed.world.terrain.base import EDGE, ROUGH_PATCH, Terrain, TerrainFeature

WEIGHT_WINDOW = 1.0   # s, weight_support_ratio averages over the last second of the run
SETTLE_TIME = 0.5     # s, the robot lands on its feet: the stability margin counts after this
POSTURE_SKIP = 1.0    # s, posture metrics (tilt, height error) exclude the first second and the start-up
# s, a crossing's tilt counts from this long before the first foot passes a terrain feature to
# this long after the last foot passed it (the posture benchmark's window, tests/benchmarks)
CROSSING_LEAD, CROSSING_SETTLE = 0.5, 1.0


class RunMetrics:
    """Accumulates the metrics of a run tick by tick, in memory independent of the run's length: the
    ticks' truth is gathered in blocks of BLOCK_STEPS physics steps, each scored into running sums
    (`PostureSums`, `estimators.scoring.StreamingScore`) and dropped; `summary` gives the metrics."""

    BLOCK_STEPS = StreamingScore.BLOCK_STEPS

    def __init__(self, config: Config, weight: float, terrain: Terrain):
        self.config = config
        self.weight = weight
        self.window_start = config.run.duration - WEIGHT_WINDOW - 0.5 * config.run.time_step
        self.fell = False
        self.left_terrain = False     # a foot or the body passed beyond the built terrain: the run ended there
        self._normal_sum = 0.0
        self._normal_count = 0
        self.min_margin = np.inf
        self.start_xy: np.ndarray | None = None
        self.start_heading = 0.0
        self.last_xy = np.zeros(2)
        self._rows: list[tuple] = []      # the block being gathered, per tick: t, quaternion, body position, feet, contact
        self._estimates: list = []        # estimates of those ticks
        self.posture = PostureSums(config, terrain)
        self.scoring = StreamingScore(config.robot.foot_radius)

    def add(self, tick: Tick) -> None:
        truth = tick.truth
        t = truth.t
        if self.start_xy is None:
            self.start_xy = truth.body_position[:2].copy()
            self.start_heading = float(np.arctan2(truth.body_rotation[1, 0], truth.body_rotation[0, 0]))
        if t >= self.window_start:
            # Six numbers: a Python sum is cheaper than numpy's per call.
            self._normal_sum += sum(tick.contacts.normal_forces.tolist())
            self._normal_count += 1
        if t >= SETTLE_TIME and tick.stability_margin < self.min_margin:
            self.min_margin = tick.stability_margin
        # One tuple per tick rather than five appends: this runs at every physics step.
        self._rows.append((t, tick.truth_quaternion, truth.body_position, truth.foot_positions, truth.foot_contact))
        if tick.estimates:
            self._estimates.extend(tick.estimates)
        if len(self._rows) == self.BLOCK_STEPS:
            self._add_block()

    def _add_block(self) -> None:
        """Score the gathered ticks into the running sums and drop them."""
        if not self._rows:
            return
        t, quaternion, position, feet, contact = (np.array(column) for column in zip(*self._rows))
        self.last_xy = position[-1, :2].copy()
        self.posture.add(t, quaternion, position, feet)
        if self._estimates:
            self.scoring.add_estimates(self._estimates)
        self.scoring.add_truth(t, quaternion, position, feet, contact)
        self._rows, self._estimates = [], []

    def _mean_speed(self, distance: float, sim_time: float) -> float | None:
        """Over the time the robot was commanded to walk: after the start-up (still, then the
        calibration poses), ramp included."""
        walking = sim_time - self.config.startup_time
        return distance / walking if walking > 0 and self.config.run.gait != "stand" else None

    def summary(self, sim_time: float, wall_s: float, ik_limited_ticks: int) -> dict:
        self._add_block()
        ratio = self._normal_sum / self._normal_count / self.weight if self._normal_count else None
        last_xy = self.last_xy
        displacement = last_xy - (self.start_xy if self.start_xy is not None else last_xy)
        heading = np.array([np.cos(self.start_heading), np.sin(self.start_heading)])
        target = self.config.gait.target
        metrics = {
            "fell": self.fell,
            "left_terrain": self.left_terrain,
            "weight_support_ratio": ratio,
            "distance_m": float(np.linalg.norm(displacement)),
            "mean_speed_mps": self._mean_speed(float(np.linalg.norm(displacement)), sim_time),
            "lateral_drift_m": float(abs(heading[0] * displacement[1] - heading[1] * displacement[0])),
            "target_error_m": float(np.linalg.norm(last_xy - target)) if target else None,
            "min_stability_margin_m": float(self.min_margin) if np.isfinite(self.min_margin) else None,
            "ik_limited_ticks": ik_limited_ticks,
            **self.posture.metrics(),
            "realtime_factor": sim_time / wall_s if wall_s > 0 else None,
            "sim_steps": int(round(sim_time / self.config.run.time_step)),
            "sim_time_s": sim_time,
            "wall_s": wall_s,
        }
        metrics.update(estimator_metrics(self.config, self.scoring))
        return metrics


class PostureSums:
    """True body tilt from level and true body height above the ground its feet stand on, minus
    the commanded height, after the first second and the start-up (whose calibration poses tilt
    the body on purpose): running sums over blocks of steps.

    The ground the feet stand on is the least-squares plane through the true ground points of
    the feet on the ground (`support_plane_heights`), under the body centre. Not the terrain under
    the body centre: that jumps by a step's height when the centre passes over its edge, and by
    a block's on rough ground, while no body standing on its legs can (docs/control.md). A foot is
    on the ground when its sphere lies within GROUND_TOLERANCE of the terrain (`feet_on_ground`,
    the support polygon's rule), whatever the contact model: DART's rigid contact reports loaded,
    resting feet out of contact for 4-50 ms at a time, and each such gap would fit the plane
    through another set of feet."""

    def __init__(self, config: Config, terrain: Terrain):
        self.stance_height = config.robot.stance_height
        self.foot_radius = config.robot.foot_radius
        self.terrain = terrain
        self.skip_until = max(POSTURE_SKIP, config.startup_time)
        self.count = 0
        self.tilt_squares = 0.0
        self.tilt_max = -np.inf
        self.height_squares = 0.0
        self.height_count = 0
        self.last_height = math.nan      # m, the last tick's, for ticks with fewer than three feet down
        self.crossings = CrossingTilts(terrain.features())

    def add(self, t: np.ndarray, quaternions: np.ndarray, positions: np.ndarray, feet: np.ndarray) -> None:
        keep = t >= self.skip_until
        if not keep.any():
            return
        tilt = body_tilt_deg(quaternions[keep])
        feet = feet[keep]
        on_ground = feet_on_ground(self.terrain, feet, self.foot_radius)
        height = support_plane_heights(positions[keep], feet, on_ground, self.foot_radius)
        height = carried_forward(height, self.last_height)
        self.last_height = float(height[-1])
        error = height[np.isfinite(height)] - self.stance_height
        self.count += len(tilt)
        self.tilt_squares += float(np.sum(tilt ** 2))
        self.tilt_max = max(self.tilt_max, float(tilt.max()))
        self.crossings.add(t[keep], tilt, feet[:, :, 0])
        self.height_squares += float(np.sum(error ** 2))
        self.height_count += len(error)

    def metrics(self) -> dict:
        crossings = self.crossings.metrics()
        if not self.count:
            return {"tilt_rms_deg": None, "tilt_max_deg": None, **crossings, "height_error_rms_m": None}
        return {"tilt_rms_deg": float(np.sqrt(self.tilt_squares / self.count)), "tilt_max_deg": self.tilt_max,
                **crossings, "height_error_rms_m": float(np.sqrt(self.height_squares / self.height_count))
                if self.height_count else None}


class CrossingTilts:
    """The true tilt's maximum while the feet cross the terrain's features (`Terrain.features`), per
    kind: `edge_tilt_max_deg` (steps, stairs, a ramp's ends) and `rough_tilt_max_deg` (rough
    patches); null where the run crossed none. A crossing lasts from CROSSING_LEAD before the first
    foot passes the feature's start to CROSSING_SETTLE after the last foot passed its end, as the
    posture benchmark counts it. Fed block by block, the last CROSSING_LEAD of ticks kept for the lead."""

    def __init__(self, features: Sequence[TerrainFeature]):
        self.features = tuple(features)
        self.entered = [math.nan] * len(self.features)     # s, the first foot past x0
        self.passed = [math.nan] * len(self.features)      # s, every foot past x1
        self.maxima = {EDGE: -math.inf, ROUGH_PATCH: -math.inf}
        self._before = (np.empty(0), np.empty(0))          # t and tilt of the last CROSSING_LEAD

    def add(self, t: np.ndarray, tilt: np.ndarray, feet_x: np.ndarray) -> None:
        """Ticks at times t (s) with the body's tilt (deg) and the feet's world x (N, 6)."""
        if not self.features or not len(t):
            return
        front, back = feet_x.max(axis=1), feet_x.min(axis=1)
        both_t, both_tilt = np.concatenate([self._before[0], t]), np.concatenate([self._before[1], tilt])
        for index, feature in enumerate(self.features):
            if math.isnan(self.entered[index]):
                self.entered[index] = _first_time(t, front > feature.x0)
            if math.isnan(self.passed[index]):
                self.passed[index] = _first_time(t, back > feature.x1)
            if math.isnan(self.entered[index]):
                continue
            end = math.inf if math.isnan(self.passed[index]) else self.passed[index] + CROSSING_SETTLE
            crossing = (both_t >= self.entered[index] - CROSSING_LEAD) & (both_t <= end)
            if crossing.any():
                self.maxima[feature.kind] = max(self.maxima[feature.kind], float(both_tilt[crossing].max()))
        recent = both_t >= t[-1] - CROSSING_LEAD
        self._before = (both_t[recent], both_tilt[recent])

    def metrics(self) -> dict:
        return {f"{kind}_tilt_max_deg": value if math.isfinite(value) else None for kind, value in self.maxima.items()}


def _first_time(t: np.ndarray, reached: np.ndarray) -> float:
    """The first of the times t where `reached` holds; NaN where it never does."""
    return float(t[np.argmax(reached)]) if reached.any() else math.nan


def support_plane_heights(body: np.ndarray, feet: np.ndarray, contact: np.ndarray, foot_radius: float) -> np.ndarray:
    """(N,) vertical height of the body origin (N, 3) above the ground its feet stand on: the
    least-squares plane through the centres of the feet in contact (N, 6, 3; contact (N, 6)),
    lowered by the foot radius along its normal (the estimators' support plane,
    `estimators.scoring.contact_planes`); NaN where that gives no plane."""
    a, b, c = contact_planes(feet - body[:, None, :], contact).T
    return -c + foot_radius * np.sqrt(1.0 + a * a + b * b)


def carried_forward(values: np.ndarray, before: float) -> np.ndarray:
    """`values` with each NaN replaced by the last finite value before it (`before` at first)."""
    values = np.concatenate([[before], values])
    last = np.where(np.isfinite(values), np.arange(len(values)), 0)
    return values[np.maximum.accumulate(last)][1:]


def body_tilt_deg(quaternions: np.ndarray) -> np.ndarray:
    """Angle between the body's z axis and the world's vertical, degrees, per (x, y, z, w) quaternion."""
    body_z_up = Rotation.from_quat(quaternions).as_matrix()[:, 2, 2]
    return np.degrees(np.arccos(np.clip(body_z_up, -1.0, 1.0)))


def estimator_metrics(config: Config, scoring: StreamingScore) -> dict:
    """The estimator's metrics (keys METRIC_KEYS), None without an estimator."""
    if config.run.estimator == "none":
        return {key: None for key in METRIC_KEYS}
    return scoring.metrics()


def score_estimates(config: Config, truth_t: np.ndarray, truth_quaternion: np.ndarray, body_position: np.ndarray,
                    feet: np.ndarray, contact: np.ndarray, estimates) -> dict:
    """Estimator metrics of a run from recorded numbers, whole arrays: the same streaming scorer
    the live run feeds block by block (`RunMetrics`), so a replay of the same estimates scores
    exactly the same. All None when there is nothing to score: no estimator, no estimate, fewer
    than two truth steps, or a run shorter than the skipped first second."""
    scoring = StreamingScore(config.robot.foot_radius)
    scoring.add_estimates(estimates)
    scoring.add_truth(truth_t, truth_quaternion, body_position, feet, contact)
    return estimator_metrics(config, scoring)


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return _clean(value.item())
    if isinstance(value, dict):
        return {key: _clean(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(item) for item in value]
    return value


def write_metrics(path: str | Path, metrics: dict) -> None:
    """Write atomically: a temporary file in the same folder, renamed over the target."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(handle, "w") as stream:
            json.dump(_clean(metrics), stream, indent=2, sort_keys=True)
            stream.write("\n")
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
