"""Accuracy metrics of an estimate stream against ground truth: pure functions of arrays.

Only scoring reads truth. Definitions (all over the scored window t >= t_truth_start + skip):
- roll_rmse_deg, pitch_rmse_deg: RMS of the wrapped ZYX roll / pitch errors (same Euler
  convention as the estimates: R = Rz(yaw) Ry(pitch) Rx(roll));
- tilt_error_max_deg: largest angle between the true and the estimated gravity direction in the
  body frame (R^T e_z), i.e. the tilt error whatever its axis;
- slope_error_deg: largest angle between the true and the estimated support-plane normal for
  t >= t_truth_start + slope_settle (2 s: "within 1 degree after 2 s");
- height_est_rmse_m: RMS error of the body height above the support plane;
- anees_tilt: average over time of the NEES of (roll, pitch) with the estimated 2x2 covariance
  (2 degrees of freedom: 2 for a consistent filter); average it over runs and compare it with
  `anees_bounds`.
A metric is None when the estimator does not give the quantity or the truth lacks it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from estimators.base import Estimate
from estimators.gating import chi2_quantile
from estimators.terrain import MIN_FOOT_SPREAD
from testbed.model.spatial import wrap_angle as wrap

METRIC_KEYS = ("roll_rmse_deg", "pitch_rmse_deg", "tilt_error_max_deg", "slope_error_deg", "height_est_rmse_m",
               "anees_tilt")


@dataclass(frozen=True)
class EstimateArrays:
    t: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    tilt_cov: np.ndarray | None         # (N, 2, 2), None if the estimator has no covariance
    terrain_roll: np.ndarray | None     # (N,), NaN before the first support plane
    terrain_pitch: np.ndarray | None
    body_height: np.ndarray | None


@dataclass(frozen=True)
class TerrainTruth:
    t: np.ndarray
    terrain_roll: np.ndarray            # (M,) rad, heading frame; NaN where fewer than 3 feet are down
    terrain_pitch: np.ndarray
    body_height: np.ndarray             # (M,) m


def estimate_arrays(estimates: Sequence[Estimate]) -> EstimateArrays:
    def column(name):
        values = [getattr(e, name) for e in estimates]
        if all(v is None for v in values):
            return None
        return np.array([np.nan if v is None else v for v in values], dtype=float)

    has_cov = bool(estimates) and all(e.attitude_cov is not None for e in estimates)
    return EstimateArrays(
        t=np.array([e.t for e in estimates], dtype=float),
        roll=np.array([e.roll for e in estimates], dtype=float),
        pitch=np.array([e.pitch for e in estimates], dtype=float),
        tilt_cov=np.array([e.attitude_cov[:2, :2] for e in estimates]) if has_cov else None,
        terrain_roll=column("terrain_roll"), terrain_pitch=column("terrain_pitch"),
        body_height=column("body_height"))


def roll_pitch_yaw(rotations: np.ndarray) -> np.ndarray:
    """(N, 3) ZYX (roll, pitch, yaw) of world_from_body matrices."""
    return Rotation.from_matrix(rotations).as_euler("ZYX")[:, ::-1]


def up_in_body(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(N, 3) R^T e_z: the gravity direction (up) in the body frame; depends on roll and pitch only."""
    return np.column_stack([-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)])


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise angle between unit vectors, accurate for small angles."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ij,ij->i", u, v))


def truth_at(t: np.ndarray, truth_t: np.ndarray, truth_rotation: np.ndarray) -> np.ndarray:
    """True rotations at the estimate times (slerp between truth samples)."""
    t = np.clip(t, truth_t[0], truth_t[-1])
    return Slerp(truth_t, Rotation.from_matrix(truth_rotation))(t).as_matrix()


def rms(values: np.ndarray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values**2))) if len(values) else None


def nees_2d(error: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    return np.einsum("ni,nij,nj->n", error, np.linalg.inv(covariance), error)


def score(estimates: EstimateArrays, truth_t: np.ndarray, truth_rotation: np.ndarray,
          terrain_truth: TerrainTruth | None = None, skip: float = 1.0, slope_settle: float = 2.0) -> dict:
    """The metrics of one run (see the module docstring); keys METRIC_KEYS, values float or None.
    ValueError when no estimate is later than the skipped first `skip` seconds."""
    sums = ScoreSums()
    sums.add(estimates, truth_t, truth_rotation, terrain_truth, truth_t[0] + skip, truth_t[0] + slope_settle)
    if not sums.scored:
        raise ValueError(f"no estimate after the first {skip} s")
    return sums.metrics()


@dataclass
class ScoreSums:
    """The running sums the metrics are made of, added block by block of estimates (`add`), so
    that a run of any length is scored in bounded memory."""
    scored: int = 0                     # estimates in the scored window
    roll_squares: float = 0.0
    roll_count: int = 0
    pitch_squares: float = 0.0
    pitch_count: int = 0
    tilt_max: float = -np.inf
    nees_sum: float = 0.0
    without_covariance: bool = False    # an estimate without a covariance: no ANEES
    with_terrain: bool = False          # an estimate with a support plane: terrain metrics
    slope_max: float = -np.inf
    height_squares: float = 0.0
    height_count: int = 0

    def add(self, estimates: EstimateArrays, truth_t: np.ndarray, truth_rotation: np.ndarray,
            terrain_truth: TerrainTruth | None, scored_from: float, slope_from: float) -> None:
        """Add the estimates scored from `scored_from` on against the truth (>= 2 steps; estimates
        outside its time span take its first or last value)."""
        scored = estimates.t >= scored_from
        if estimates.tilt_cov is None and len(estimates.t):
            self.without_covariance = True
        if not scored.any():
            return
        self.scored += int(np.count_nonzero(scored))
        true_rpy = roll_pitch_yaw(truth_at(estimates.t[scored], truth_t, truth_rotation))
        error = np.column_stack([wrap(estimates.roll[scored] - true_rpy[:, 0]),
                                 wrap(estimates.pitch[scored] - true_rpy[:, 1])])
        tilt = angle_between(up_in_body(estimates.roll[scored], estimates.pitch[scored]),
                             up_in_body(true_rpy[:, 0], true_rpy[:, 1]))
        self.roll_squares, self.roll_count = _add_squares(self.roll_squares, self.roll_count, error[:, 0])
        self.pitch_squares, self.pitch_count = _add_squares(self.pitch_squares, self.pitch_count, error[:, 1])
        self.tilt_max = max(self.tilt_max, float(tilt.max()))
        if estimates.tilt_cov is not None:
            self.nees_sum += float(np.sum(nees_2d(error, estimates.tilt_cov[scored])))
        if terrain_truth is not None and estimates.terrain_roll is not None:
            self.with_terrain = True
            self._add_terrain(estimates, terrain_truth, scored_from, slope_from)

    def _add_terrain(self, estimates: EstimateArrays, truth: TerrainTruth, height_from: float,
                     slope_from: float) -> None:
        def true_at(values):
            return np.interp(estimates.t, truth.t, values)

        estimated_normal = up_in_body(estimates.terrain_roll, estimates.terrain_pitch)
        true_normal = up_in_body(true_at(truth.terrain_roll), true_at(truth.terrain_pitch))
        slope_error = angle_between(estimated_normal, true_normal)[estimates.t >= slope_from]
        slope_error = slope_error[np.isfinite(slope_error)]
        if len(slope_error):
            self.slope_max = max(self.slope_max, float(slope_error.max()))
        if estimates.body_height is not None:
            height_error = (estimates.body_height - true_at(truth.body_height))[estimates.t >= height_from]
            self.height_squares, self.height_count = _add_squares(self.height_squares, self.height_count,
                                                                  height_error)

    def metrics(self) -> dict:
        """Keys METRIC_KEYS; all None when no estimate was scored."""
        if not self.scored:
            return {key: None for key in METRIC_KEYS}
        return {
            "roll_rmse_deg": _degrees_or_none(_root_mean(self.roll_squares, self.roll_count)),
            "pitch_rmse_deg": _degrees_or_none(_root_mean(self.pitch_squares, self.pitch_count)),
            "tilt_error_max_deg": float(np.degrees(self.tilt_max)),
            "slope_error_deg": float(np.degrees(self.slope_max)) if np.isfinite(self.slope_max) else None,
            "height_est_rmse_m": _root_mean(self.height_squares, self.height_count) if self.with_terrain else None,
            "anees_tilt": None if self.without_covariance else self.nees_sum / self.scored,
        }


def _add_squares(total: float, count: int, values: np.ndarray) -> tuple[float, int]:
    """The running sum of squares and count of the finite values."""
    values = values[np.isfinite(values)]
    return total + float(np.sum(values ** 2)), count + len(values)


def _root_mean(squares: float, count: int) -> float | None:
    return float(np.sqrt(squares / count)) if count else None


def _degrees_or_none(value: float | None) -> float | None:
    return None if value is None else float(np.degrees(value))


class StreamingScore:
    """`score` of a run whose truth and estimates arrive in chunks of any size, in memory bounded
    by BLOCK_STEPS: the truth is cut into blocks of BLOCK_STEPS physics steps counted from the first,
    whatever the chunks, and each block scores the estimates up to its last time, so that the
    same run fed whole or step by step gives the same numbers.

    Truth per step: time, world_from_body quaternion (x, y, z, w), body position, foot sphere
    centres and contact flags (the support plane's inputs, see `support_plane_truth`)."""

    BLOCK_STEPS = 4096

    def __init__(self, foot_radius: float, skip: float = 1.0, slope_settle: float = 2.0):
        self.foot_radius = foot_radius
        self.skip = skip
        self.slope_settle = slope_settle
        self.sums = ScoreSums()
        self.steps = 0
        self._start: float | None = None
        self._truth: list[tuple[np.ndarray, ...]] = []      # chunks of the block being filled
        self._buffered = 0
        self._estimates: list[EstimateArrays] = []          # not scored yet
        self._previous: _TruthBlock | None = None           # the last block scored

    def add_truth(self, t: np.ndarray, quaternion: np.ndarray, body_position: np.ndarray, feet: np.ndarray,
                  contact: np.ndarray) -> None:
        columns = tuple(np.asarray(column) for column in (t, quaternion, body_position, feet, contact))
        if self._start is None and len(columns[0]):
            self._start = float(columns[0][0])
        while len(columns[0]):
            room = self.BLOCK_STEPS - self._buffered
            self._truth.append(tuple(column[:room] for column in columns))
            self._buffered += min(room, len(columns[0]))
            columns = tuple(column[room:] for column in columns)
            if self._buffered == self.BLOCK_STEPS:
                self._score_block()

    def add_estimates(self, estimates: Sequence[Estimate] | EstimateArrays) -> None:
        arrays = estimates if isinstance(estimates, EstimateArrays) else estimate_arrays(estimates)
        if len(arrays.t):
            self._estimates.append(arrays)

    def metrics(self) -> dict:
        """Keys METRIC_KEYS, over everything added: all None with fewer than two truth steps or no
        estimate after the skipped first seconds."""
        if self._buffered:
            self._score_block()
        if self._previous is not None and self._estimates:
            self._score(_concatenate(self._estimates), self._previous)
            self._estimates = []
        return self.sums.metrics()

    def _score_block(self) -> None:
        t, quaternion, body_position, feet, contact = (np.concatenate(parts) for parts in zip(*self._truth))
        self._truth, self._buffered = [], 0
        self.steps += len(t)
        if np.any(np.diff(t) <= 0) or (self._previous is not None and t[0] <= self._previous.t[-1]):
            raise ValueError("the truth's times do not increase")
        rotation = Rotation.from_quat(quaternion).as_matrix()
        terrain = support_plane_truth(t, feet, contact, body_position, rotation, self.foot_radius)
        block = _TruthBlock(t, rotation, terrain)
        if self._previous is not None:
            block = self._previous.last_step().followed_by(block)
        if len(block.t) < 2:
            self._previous = block
            return
        if self._estimates:
            estimates = _concatenate(self._estimates)
            now = estimates.t <= block.t[-1]
            self._estimates = [_select(estimates, ~now)] if not now.all() else []
            self._score(_select(estimates, now), block)
        self._previous = block

    def _score(self, estimates: EstimateArrays, block: "_TruthBlock") -> None:
        if len(block.t) < 2:
            return
        self.sums.add(estimates, block.t, block.rotation, block.terrain, self._start + self.skip,
                      self._start + self.slope_settle)


@dataclass(frozen=True)
class _TruthBlock:
    t: np.ndarray
    rotation: np.ndarray
    terrain: TerrainTruth

    def last_step(self) -> "_TruthBlock":
        terrain = self.terrain
        return _TruthBlock(self.t[-1:], self.rotation[-1:], TerrainTruth(
            terrain.t[-1:], terrain.terrain_roll[-1:], terrain.terrain_pitch[-1:], terrain.body_height[-1:]))

    def followed_by(self, other: "_TruthBlock") -> "_TruthBlock":
        a, b = self.terrain, other.terrain
        terrain = TerrainTruth(*(np.concatenate([x, y]) for x, y in zip(
            (a.t, a.terrain_roll, a.terrain_pitch, a.body_height), (b.t, b.terrain_roll, b.terrain_pitch, b.body_height))))
        return _TruthBlock(np.concatenate([self.t, other.t]), np.concatenate([self.rotation, other.rotation]), terrain)


def _concatenate(blocks: list[EstimateArrays]) -> EstimateArrays:
    """One EstimateArrays of several: a column missing from some (None) is NaN there; the
    covariance is None if any lacks it."""
    if len(blocks) == 1:
        return blocks[0]

    def column(name):
        values = [getattr(block, name) for block in blocks]
        if all(value is None for value in values):
            return None
        return np.concatenate([np.full(len(block.t), np.nan) if value is None else value
                               for block, value in zip(blocks, values)])

    covariances = [block.tilt_cov for block in blocks]
    return EstimateArrays(np.concatenate([block.t for block in blocks]), column("roll"), column("pitch"),
                          None if any(c is None for c in covariances) else np.concatenate(covariances),
                          column("terrain_roll"), column("terrain_pitch"), column("body_height"))


def _select(estimates: EstimateArrays, rows: np.ndarray) -> EstimateArrays:
    return EstimateArrays(*(None if column is None else column[rows] for column in (
        estimates.t, estimates.roll, estimates.pitch, estimates.tilt_cov, estimates.terrain_roll,
        estimates.terrain_pitch, estimates.body_height)))


def support_plane_truth(t: np.ndarray, feet_world: np.ndarray, contact: np.ndarray, body_position: np.ndarray,
                        body_rotation: np.ndarray, foot_radius: float, normal_forces: np.ndarray | None = None,
                        min_force: float = 0.0) -> TerrainTruth:
    """Terrain truth with the estimators' definition: the least-squares plane through the centres of
    the feet in contact (and, given the true normal forces, carrying at least `min_force`, as the
    estimators' planted feet), lowered by the foot radius; angles in the true heading frame.
    As `estimators.terrain.fit_plane`, fewer than three feet, or feet closer than MIN_FOOT_SPREAD
    to a line, give no plane (NaN). The steps are fitted in groups that share a support pattern."""
    yaw = roll_pitch_yaw(body_rotation)[:, 2]
    support = np.asarray(contact, dtype=bool)
    if normal_forces is not None:
        support = support & (np.asarray(normal_forces) >= min_force)
    feet = np.asarray(feet_world, dtype=float) - np.asarray(body_position, dtype=float)[:, None, :]
    coefficients = np.full((len(t), 3), np.nan)
    patterns = support @ (1 << np.arange(support.shape[1]))
    for pattern in np.unique(patterns):
        steps = np.flatnonzero(patterns == pattern)
        coefficients[steps] = support_planes(feet[steps][:, support[steps[0]]])
    a, b, c = coefficients.T
    height = -c / np.sqrt(1.0 + a * a + b * b) + foot_radius
    roll, pitch = heading_terrain_tilt(a, b, yaw)
    return TerrainTruth(np.asarray(t, dtype=float), roll, pitch, height)


def support_planes(points: np.ndarray) -> np.ndarray:
    """(N, 3) coefficients (a, b, c) of the least-squares planes z = a x + b y + c through each of
    N sets of M points (N, M, 3); NaN where M < 3 or the points' smallest spread (the smaller
    principal standard deviation of their x, y) is below MIN_FOOT_SPREAD."""
    planes = np.full((len(points), 3), np.nan)
    if points.shape[1] < 3:
        return planes
    xy = points[:, :, :2] - points[:, :, :2].mean(axis=1, keepdims=True)
    scatter = np.einsum("nki,nkj->nij", xy, xy) / points.shape[1]
    sxx, syy, sxy = scatter[:, 0, 0], scatter[:, 1, 1], scatter[:, 0, 1]
    smallest_variance = 0.5 * (sxx + syy) - np.hypot(0.5 * (sxx - syy), sxy)
    spread = np.flatnonzero(np.sqrt(np.maximum(smallest_variance, 0.0)) >= MIN_FOOT_SPREAD)
    design = np.concatenate([points[spread, :, :2], np.ones((len(spread), points.shape[1], 1))], axis=2)
    normal_matrix = np.einsum("nki,nkj->nij", design, design)
    moments = np.einsum("nki,nk->ni", design, points[spread, :, 2])
    planes[spread] = np.linalg.solve(normal_matrix, moments[..., None])[..., 0]
    return planes


def heading_terrain_tilt(a: np.ndarray, b: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Terrain (roll, pitch) of planes z = a x + b y + c seen from headings `yaw`: the angles of
    `estimators.terrain.heading_terrain_angles`, for arrays."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    a_h, b_h = a * cy + b * sy, -a * sy + b * cy
    return np.arcsin(b_h / np.sqrt(1.0 + a_h * a_h + b_h * b_h)), np.arctan(-a_h)


def anees_bounds(runs: int, dof: int = 2, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square bounds of the ANEES averaged over `runs` independent runs
    (Bar-Shalom et al. 2001, section 5.4.2): runs * ANEES ~ chi2(runs * dof)."""
    tail = 0.5 * (1.0 - probability)
    return chi2_quantile(tail, runs * dof) / runs, chi2_quantile(1.0 - tail, runs * dof) / runs
