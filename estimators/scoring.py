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
Full-state estimators (those that give position and velocity), in the start frame (origin at the
true body origin at the first truth step, x along its heading, z up: the estimators' frame):
- position_rmse_m: evo's APE (translation part, no alignment beyond the start pose) of the
  estimated body position, on the trajectory decimated to DECIMATION_HZ;
- position_drift_pct: the last estimate's horizontal position error over the distance travelled
  (evo's path length of the decimated true trajectory), in %;
- velocity_rmse_mps: RMS of the norm of the body origin's velocity error (truth: the position's
  finite differences between physics steps);
- yaw_error_final_deg: the last estimate's yaw error (wrapped, absolute);
- anees_pose: average over time of the NEES of position, velocity and (roll, pitch, yaw), each
  with its own 3x3 covariance (the estimates carry no cross-covariances): expected 9 for a
  consistent filter, compared with `anees_bounds(runs, dof=9)`.
A metric is None when the estimator does not give the quantity or the truth lacks it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from functools import cached_property
from operator import attrgetter

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evo.core import metrics as evo_metrics
from evo.core.trajectory import PoseTrajectory3D

from estimators.base import ROW_FIELDS, SHARED_FIELDS, Estimate, EstimateRows, Estimates
from estimators.gating import chi2_quantile
from estimators.terrain import MIN_FOOT_SPREAD
from testbed.model.spatial import wrap_angle as wrap

SAME_TIME = 1e-9         # s: the datasets' time resolution; sample and step times differ by rounding within it
ATTITUDE_KEYS = ("roll_rmse_deg", "pitch_rmse_deg", "tilt_error_max_deg", "slope_error_deg", "height_est_rmse_m",
                 "anees_tilt")
POSE_KEYS = ("position_drift_pct", "position_rmse_m", "velocity_rmse_mps", "yaw_error_final_deg", "anees_pose")
METRIC_KEYS = ATTITUDE_KEYS + POSE_KEYS
DECIMATION_HZ = 10.0      # the trajectory evo scores


@dataclass(frozen=True)
class EstimateArrays:
    t: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    tilt_cov: np.ndarray | None         # (N, 2, 2), None if the estimator has no covariance
    terrain_roll: np.ndarray | None     # (N,), NaN before the first support plane
    terrain_pitch: np.ndarray | None
    body_height: np.ndarray | None
    yaw: np.ndarray | None = None
    attitude_cov: np.ndarray | None = None  # (N, 3, 3) of (roll, pitch, yaw)
    position: np.ndarray | None = None      # (N, 3), None if the estimator gives none
    velocity: np.ndarray | None = None
    position_cov: np.ndarray | None = None  # (N, 3, 3)
    velocity_cov: np.ndarray | None = None


@dataclass(frozen=True)
class TerrainTruth:
    t: np.ndarray
    terrain_roll: np.ndarray            # (M,) rad, heading frame; NaN where fewer than 3 feet are down
    terrain_pitch: np.ndarray
    body_height: np.ndarray             # (M,) m


def estimate_arrays(estimates: Sequence[Estimate]) -> EstimateArrays:
    """The estimates' fields as columns (those of `Estimates` part by part: `part_column`)."""
    parts = estimate_parts(estimates)

    def floats(name):
        return np.concatenate([part_column(part, name)[0] for part in parts]) if parts else np.array([], dtype=float)

    def column(name):
        """Floats, NaN where an estimate has None; None when all have None."""
        per_part = [part_column(part, name) for part in parts]
        return None if all(all_none for _, all_none in per_part) else np.concatenate([c for c, _ in per_part])

    def stacked_column(name):
        """None unless every estimate has an array."""
        per_part = [part_column(part, name)[0] for part in parts]
        return None if not per_part or any(c is None for c in per_part) else np.concatenate(per_part)

    attitude_cov = stacked_column("attitude_cov")
    return EstimateArrays(
        t=floats("t"), roll=floats("roll"), pitch=floats("pitch"),
        tilt_cov=None if attitude_cov is None else attitude_cov[:, :2, :2],
        terrain_roll=column("terrain_roll"), terrain_pitch=column("terrain_pitch"),
        body_height=column("body_height"), yaw=floats("yaw"),
        attitude_cov=attitude_cov, position=stacked_column("position"), velocity=stacked_column("velocity"),
        position_cov=stacked_column("position_cov"), velocity_cov=stacked_column("velocity_cov"))


SCALAR_FIELDS = frozenset({"t", "roll", "pitch", "yaw", "terrain_roll", "terrain_pitch", "body_height"})


@dataclass
class RowsRun:
    """Consecutive `EstimateRows` of `Estimates`, whose columns are taken together."""
    parts: list[EstimateRows]

    def row_column(self, name: str) -> np.ndarray:
        """The column of a row field ("t" or one of ESTIMATE_ROWS): one gather from each run of
        parts that share their arrays."""
        columns = [(part.t if name == "t" else part.rows[name])[index] for part, index in self._gathers]
        return np.concatenate(columns) if len(columns) > 1 else columns[0]

    def shared_values(self, name: str) -> list:
        """The parts' values of a field they share among their estimates (`SHARED_FIELDS`)."""
        return self._shared[name]

    @cached_property
    def counts(self) -> np.ndarray:
        """The parts' numbers of estimates."""
        return np.fromiter((part.stop - part.first for part in self.parts), dtype=np.intp, count=len(self.parts))

    @cached_property
    def _gathers(self) -> list[tuple[EstimateRows, np.ndarray]]:
        """(the first of consecutive parts with the same arrays, the indices of their rows in them)."""
        parts, counts = self.parts, self.counts
        edges = [k for k in range(1, len(parts)) if parts[k].rows is not parts[k - 1].rows
                 or parts[k].t is not parts[k - 1].t]
        bounds = [0, *edges, len(parts)]
        gathers = []
        for first, stop in zip(bounds[:-1], bounds[1:]):
            starts = np.fromiter((part.first for part in parts[first:stop]), dtype=np.intp, count=stop - first)
            run_counts = counts[first:stop]
            # row k of the run is row k + (its part's start - the rows before that part) of the arrays
            offsets = np.repeat(starts - (np.cumsum(run_counts) - run_counts), run_counts)
            gathers.append((parts[first], np.arange(len(offsets)) + offsets))
        return gathers

    @cached_property
    def _shared(self) -> dict[str, list]:
        columns = zip(*[part.step + part.pose_covariances for part in self.parts])
        return dict(zip(SHARED_FIELDS, map(list, columns)))


def estimate_parts(estimates: Sequence[Estimate]) -> list[Sequence[Estimate] | RowsRun]:
    """The estimates in non-empty parts: lists of Estimate objects and runs of EstimateRows."""
    if not isinstance(estimates, Estimates):
        return [estimates] if len(estimates) else []
    parts: list[Sequence[Estimate] | RowsRun] = []
    for part in estimates.parts:
        if not isinstance(part, EstimateRows):
            parts.append(part)
        elif parts and isinstance(parts[-1], RowsRun):
            parts[-1].parts.append(part)
        else:
            parts.append(RowsRun([part]))
    return parts


def part_column(estimates: Sequence[Estimate] | RowsRun, name: str) -> tuple[np.ndarray | None, bool]:
    """(column, whether every estimate has None) of one field of a part (`estimate_parts`): a
    scalar field's floats, NaN where an estimate has None; an array field's arrays stacked, None
    unless every estimate has one."""
    if isinstance(estimates, RowsRun):
        return rows_column(estimates, name)
    values = list(map(attrgetter(name), estimates))
    if name in SCALAR_FIELDS:
        return np.array(values, dtype=float), values.count(None) == len(values)
    column = stacked(values)
    return column, column is None and all(value is None for value in values)


def rows_column(run: RowsRun, name: str) -> tuple[np.ndarray | None, bool]:
    """`part_column` of consecutive rows: the row fields' columns, the shared values repeated."""
    if name == "t" or name in ROW_FIELDS:
        return run.row_column(name), False
    values = run.shared_values(name)
    if name in SCALAR_FIELDS:
        return np.repeat(np.array(values, dtype=float), run.counts), values.count(None) == len(values)
    if any(value is None for value in values):
        return None, all(value is None for value in values)
    return np.repeat(np.array(values, dtype=float), run.counts, axis=0), False


def stacked(arrays: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """The arrays stacked; None unless all are arrays. An estimator may hand the same array object
    to consecutive estimates (a covariance that changes only at its filter steps): each run of one
    object is converted once and repeated."""
    identities = np.fromiter(map(id, arrays), dtype=np.uint64, count=len(arrays))
    if not len(arrays) or np.any(identities == id(None)):
        return None
    firsts = np.flatnonzero(np.concatenate([[True], identities[1:] != identities[:-1]]))
    distinct = np.array([arrays[k] for k in firsts.tolist()], dtype=float)
    if len(firsts) == len(arrays):
        return distinct
    return np.repeat(distinct, np.diff(np.append(firsts, len(arrays))), axis=0)


def roll_pitch_yaw(rotations: np.ndarray) -> np.ndarray:
    """(N, 3) ZYX (roll, pitch, yaw) of world_from_body matrices R = Rz(yaw) Ry(pitch) Rx(roll),
    read off the matrices' entries (scipy's `as_euler` would first turn every matrix into a
    quaternion, which costs more than the scoring around it)."""
    roll = np.arctan2(rotations[:, 2, 1], rotations[:, 2, 2])
    pitch = np.arctan2(-rotations[:, 2, 0], np.hypot(rotations[:, 2, 1], rotations[:, 2, 2]))
    yaw = np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])
    return np.column_stack([roll, pitch, yaw])


def up_in_body(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(N, 3) R^T e_z: the gravity direction (up) in the body frame; depends on roll and pitch only."""
    return np.column_stack([-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)])


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise angle between unit vectors, accurate for small angles."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ij,ij->i", u, v))


def truth_at(t: np.ndarray, truth_t: np.ndarray, truth_rotation: np.ndarray) -> np.ndarray:
    """True rotations at the estimate times: the truth's own at its steps (within SAME_TIME),
    slerp between them."""
    t = np.clip(t, truth_t[0], truth_t[-1])
    right = np.minimum(np.searchsorted(truth_t, t), len(truth_t) - 1)
    left = np.maximum(right - 1, 0)
    index = np.where(np.abs(truth_t[left] - t) < np.abs(truth_t[right] - t), left, right)
    at_a_step = np.abs(truth_t[index] - t) <= SAME_TIME
    rotations = truth_rotation[index]
    if not at_a_step.all():
        between = ~at_a_step
        rotations[between] = Slerp(truth_t, Rotation.from_matrix(truth_rotation))(t[between]).as_matrix()
    return rotations


def rms(values: np.ndarray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values**2))) if len(values) else None


def nees_2d(error: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(N,) e^T C^-1 e of N errors (N, k) with their covariances (N, k, k)."""
    return np.einsum("ni,ni->n", error, np.linalg.solve(covariance, error[..., None])[..., 0])


@dataclass(frozen=True)
class StartFrame:
    """The true body pose at the first truth step: the frame full-state estimates are given in."""
    position: np.ndarray      # (3,) m, world
    yaw: float                # rad

    @classmethod
    def of(cls, position: np.ndarray, rotation: np.ndarray) -> "StartFrame":
        return cls(np.array(position, dtype=float), float(np.arctan2(rotation[1, 0], rotation[0, 0])))

    def to_start(self, vectors: np.ndarray) -> np.ndarray:
        """(N, 3) world vectors turned into the start frame (by -yaw)."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.column_stack([c * vectors[:, 0] + s * vectors[:, 1], -s * vectors[:, 0] + c * vectors[:, 1],
                                vectors[:, 2]])


@dataclass(frozen=True)
class PoseTruth:
    """True body position and velocity at each truth step (velocity: finite differences, NaN
    at a block's first step, which has no predecessor)."""
    t: np.ndarray
    position: np.ndarray      # (M, 3) m, world
    velocity: np.ndarray      # (M, 3) m/s, world, mean over the step that ends at t

    @classmethod
    def of(cls, t: np.ndarray, position: np.ndarray) -> "PoseTruth":
        velocity = np.full_like(position, np.nan)
        velocity[1:] = np.diff(position, axis=0) / np.diff(t)[:, None]
        return cls(t, position, velocity)

    def at(self, t: np.ndarray, frame: StartFrame) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at times t in the start frame: positions interpolated linearly,
        the velocity of the step each time falls in (t clipped to the truth's span)."""
        t = np.clip(t, self.t[0], self.t[-1])
        position = np.column_stack([np.interp(t, self.t, self.position[:, i]) for i in range(3)])
        step = np.clip(np.searchsorted(self.t, t, side="left"), 1, len(self.t) - 1)
        return frame.to_start(position - frame.position), frame.to_start(self.velocity[step])


@dataclass
class PoseSums:
    """The running sums of the full-state metrics, and the trajectory decimated to DECIMATION_HZ
    (the only part that grows with the run: 10 poses a second) that evo scores."""
    scored: int = 0
    without_pose: bool = False          # an estimate without a position: no pose metrics
    velocity_squares: float = 0.0
    velocity_count: int = 0
    nees_sum: float = 0.0
    nees_count: int = 0
    final_error: np.ndarray | None = None       # (3,) m, of the last estimate
    final_yaw_error: float | None = None        # rad
    next_slot: int = 0                  # the next decimation slot (index of 1 / DECIMATION_HZ from the start)
    decimated: list = field(default_factory=list)   # per block: t, estimated and true positions and quaternions

    def add(self, estimates: EstimateArrays, scored: np.ndarray, attitude_error: np.ndarray,
            true_rotation: np.ndarray, true_yaw: np.ndarray, truth: PoseTruth, frame: StartFrame,
            start: float) -> None:
        """Add the estimates `scored` (mask), given their (roll, pitch) errors, true rotations
        (world_from_body, one per scored estimate) and true ZYX yaws (rad, world frame)."""
        if estimates.position is None or estimates.velocity is None:
            self.without_pose = True
            return
        t = estimates.t[scored]
        true_position, true_velocity = truth.at(t, frame)
        position_error = estimates.position[scored] - true_position
        velocity_error = estimates.velocity[scored] - true_velocity
        yaw_error = wrap(estimates.yaw[scored] - (true_yaw - frame.yaw))
        self.scored += len(t)
        self.velocity_squares, self.velocity_count = _add_squares(
            self.velocity_squares, self.velocity_count, np.linalg.norm(velocity_error, axis=1))
        self.final_error, self.final_yaw_error = position_error[-1], float(yaw_error[-1])
        if estimates.position_cov is not None and estimates.velocity_cov is not None \
                and estimates.attitude_cov is not None:
            attitude = np.column_stack([attitude_error, yaw_error])
            nees = (nees_2d(position_error, estimates.position_cov[scored])
                    + nees_2d(velocity_error, estimates.velocity_cov[scored])
                    + nees_2d(attitude, estimates.attitude_cov[scored]))
            nees = nees[np.isfinite(nees)]
            self.nees_sum += float(np.sum(nees))
            self.nees_count += len(nees)
        self._decimate(t, estimates, scored, true_position, true_rotation, frame, start)

    def _decimate(self, t: np.ndarray, estimates: EstimateArrays, scored: np.ndarray, true_position: np.ndarray,
                  true_rotation: np.ndarray, frame: StartFrame, start: float) -> None:
        """Keep the first estimate of each 1 / DECIMATION_HZ slot from the start."""
        slots = np.floor((t - start) * DECIMATION_HZ).astype(np.int64)
        first = np.flatnonzero((slots >= self.next_slot) & np.concatenate([[True], slots[1:] != slots[:-1]]))
        if not len(first):
            return
        self.next_slot = int(slots[first[-1]]) + 1
        true_quaternion = (Rotation.from_euler("z", -frame.yaw) * Rotation.from_matrix(true_rotation[first])).as_quat()
        rows = np.flatnonzero(scored)[first]
        euler = np.column_stack([estimates.yaw[rows], estimates.pitch[rows], estimates.roll[rows]])
        estimated_quaternion = Rotation.from_euler("ZYX", euler).as_quat()
        self.decimated.append((t[first], estimates.position[rows], true_position[first],
                               estimated_quaternion, true_quaternion))

    def metrics(self) -> dict:
        if not self.scored or self.without_pose:
            return {key: None for key in POSE_KEYS}
        rmse, distance = trajectory_errors(*(np.concatenate(column) for column in zip(*self.decimated)))
        horizontal = float(np.hypot(*self.final_error[:2]))
        return {
            "position_drift_pct": 100.0 * horizontal / distance if distance > 0 else None,
            "position_rmse_m": rmse,
            "velocity_rmse_mps": _root_mean(self.velocity_squares, self.velocity_count),
            "yaw_error_final_deg": float(np.degrees(abs(self.final_yaw_error))),
            "anees_pose": self.nees_sum / self.nees_count if self.nees_count else None,
        }


XYZW_TO_WXYZ = [3, 0, 1, 2]


def trajectory_errors(t: np.ndarray, estimated: np.ndarray, true: np.ndarray, estimated_quaternion: np.ndarray,
                      true_quaternion: np.ndarray) -> tuple[float | None, float]:
    """(evo's APE RMSE of the translation, evo's path length of the true trajectory) of paired
    poses (quaternions x, y, z, w) in one frame, without alignment; RMSE None under 2 poses."""
    if len(t) < 2:
        return None, 0.0
    reference = PoseTrajectory3D(positions_xyz=true, orientations_quat_wxyz=true_quaternion[:, XYZW_TO_WXYZ],
                                 timestamps=t)
    estimate = PoseTrajectory3D(positions_xyz=estimated,
                                orientations_quat_wxyz=estimated_quaternion[:, XYZW_TO_WXYZ], timestamps=t)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    return float(ape.get_statistic(evo_metrics.StatisticsType.rmse)), float(reference.path_length)


def score(estimates: EstimateArrays, truth_t: np.ndarray, truth_rotation: np.ndarray,
          terrain_truth: TerrainTruth | None = None, skip: float = 1.0, slope_settle: float = 2.0,
          truth_position: np.ndarray | None = None) -> dict:
    """The metrics of one run (see the module docstring); keys METRIC_KEYS, values float or None
    (the full-state ones None without `truth_position`, (M, 3) m, world). ValueError when no
    estimate is later than the skipped first `skip` seconds."""
    sums = ScoreSums()
    pose = None
    if truth_position is not None:
        pose = PoseTruth.of(truth_t, truth_position), StartFrame.of(truth_position[0], truth_rotation[0])
    sums.add(estimates, truth_t, truth_rotation, terrain_truth, truth_t[0] + skip, truth_t[0] + slope_settle, pose)
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
    pose: PoseSums = field(default_factory=PoseSums)

    def add(self, estimates: EstimateArrays, truth_t: np.ndarray, truth_rotation: np.ndarray,
            terrain_truth: TerrainTruth | None, scored_from: float, slope_from: float,
            pose_truth: tuple[PoseTruth, StartFrame] | None = None) -> None:
        """Add the estimates scored from `scored_from` on against the truth (>= 2 steps; estimates
        outside its time span take its first or last value); with `pose_truth` (the true body
        positions and the start frame) the full-state metrics too."""
        scored = estimates.t >= scored_from
        if estimates.tilt_cov is None and len(estimates.t):
            self.without_covariance = True
        if not scored.any():
            return
        self.scored += int(np.count_nonzero(scored))
        true_rotation = truth_at(estimates.t[scored], truth_t, truth_rotation)
        true_rpy = roll_pitch_yaw(true_rotation)
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
        if pose_truth is not None:
            self.pose.add(estimates, scored, error, true_rotation, true_rpy[:, 2], *pose_truth, scored_from)

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
        return {**self._attitude_metrics(), **self.pose.metrics()}

    def _attitude_metrics(self) -> dict:
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
        self._frame: StartFrame | None = None               # the true pose at the first step

    def add_truth(self, t: np.ndarray, quaternion: np.ndarray, body_position: np.ndarray, feet: np.ndarray,
                  contact: np.ndarray) -> None:
        columns = tuple(np.asarray(column) for column in (t, quaternion, body_position, feet, contact))
        if self._start is None and len(columns[0]):
            self._start = float(columns[0][0])
            self._frame = StartFrame.of(columns[2][0], Rotation.from_quat(columns[1][0]).as_matrix())
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
            self._score(concatenated(self._estimates), self._previous)
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
        block = _TruthBlock(t, rotation, terrain, np.asarray(body_position, dtype=float))
        if self._previous is not None:
            block = self._previous.last_step().followed_by(block)
        if len(block.t) < 2:
            self._previous = block
            return
        if self._estimates:
            estimates = concatenated(self._estimates)
            now, later = _split(estimates, estimates.t <= block.t[-1])
            self._estimates = [later] if len(later.t) else []
            self._score(now, block)
        self._previous = block

    def _score(self, estimates: EstimateArrays, block: "_TruthBlock") -> None:
        if len(block.t) < 2:
            return
        self.sums.add(estimates, block.t, block.rotation, block.terrain, self._start + self.skip,
                      self._start + self.slope_settle, (PoseTruth.of(block.t, block.position), self._frame))


@dataclass(frozen=True)
class _TruthBlock:
    t: np.ndarray
    rotation: np.ndarray
    terrain: TerrainTruth
    position: np.ndarray        # (M, 3) m, world

    def last_step(self) -> "_TruthBlock":
        terrain = self.terrain
        return _TruthBlock(self.t[-1:], self.rotation[-1:], TerrainTruth(
            terrain.t[-1:], terrain.terrain_roll[-1:], terrain.terrain_pitch[-1:], terrain.body_height[-1:]),
            self.position[-1:])

    def followed_by(self, other: "_TruthBlock") -> "_TruthBlock":
        a, b = self.terrain, other.terrain
        terrain = TerrainTruth(*(np.concatenate([x, y]) for x, y in zip(
            (a.t, a.terrain_roll, a.terrain_pitch, a.body_height), (b.t, b.terrain_roll, b.terrain_pitch, b.body_height))))
        return _TruthBlock(np.concatenate([self.t, other.t]), np.concatenate([self.rotation, other.rotation]), terrain,
                           np.concatenate([self.position, other.position]))


def concatenated(blocks: list[EstimateArrays]) -> EstimateArrays:
    """One EstimateArrays of several (at least one), as `estimate_arrays` of all their estimates:
    a terrain column missing from some (None) is NaN there; another column is None if any lacks it."""
    if len(blocks) == 1:
        return blocks[0]

    def column(name):
        values = [getattr(block, name) for block in blocks]
        if all(value is None for value in values):
            return None
        return np.concatenate([np.full(len(block.t), np.nan) if value is None else value
                               for block, value in zip(blocks, values)])

    def joined(name):
        values = [getattr(block, name) for block in blocks]
        return None if any(value is None for value in values) else np.concatenate(values)

    return EstimateArrays(**{name: column(name) if name in NAN_FILLED else joined(name)
                             for name in (f.name for f in fields(EstimateArrays))})


NAN_FILLED = frozenset({"terrain_roll", "terrain_pitch", "body_height"})   # columns NaN where absent


def _select(estimates: EstimateArrays, rows: np.ndarray | slice) -> EstimateArrays:
    return EstimateArrays(**{f.name: None if getattr(estimates, f.name) is None else getattr(estimates, f.name)[rows]
                             for f in fields(EstimateArrays)})


def _split(estimates: EstimateArrays, selected: np.ndarray) -> tuple[EstimateArrays, EstimateArrays]:
    """(the estimates `selected`, the others). Estimates in time order split at one row: the two
    parts are views, not copies (a run's estimates are split at every truth block)."""
    count = int(np.count_nonzero(selected))
    if selected[:count].all():
        return _select(estimates, slice(0, count)), _select(estimates, slice(count, None))
    return _select(estimates, selected), _select(estimates, ~selected)


def support_plane_truth(t: np.ndarray, feet_world: np.ndarray, contact: np.ndarray, body_position: np.ndarray,
                        body_rotation: np.ndarray, foot_radius: float, normal_forces: np.ndarray | None = None,
                        min_force: float = 0.0) -> TerrainTruth:
    """Terrain truth with the estimators' definition: the least-squares plane through the centres of
    the feet in contact (and, given the true normal forces, carrying at least `min_force`, as the
    estimators' planted feet), lowered by the foot radius; angles in the true heading frame.
    As `estimators.terrain.fit_plane`, fewer than three feet, or feet closer than MIN_FOOT_SPREAD
    to a line, give no plane (NaN)."""
    yaw = roll_pitch_yaw(body_rotation)[:, 2]
    support = np.asarray(contact, dtype=bool)
    if normal_forces is not None:
        support = support & (np.asarray(normal_forces) >= min_force)
    feet = np.asarray(feet_world, dtype=float) - np.asarray(body_position, dtype=float)[:, None, :]
    a, b, c = contact_planes(feet, support).T
    height = -c / np.sqrt(1.0 + a * a + b * b) + foot_radius
    roll, pitch = heading_terrain_tilt(a, b, yaw)
    return TerrainTruth(np.asarray(t, dtype=float), roll, pitch, height)


def contact_planes(feet: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """(N, 3) `support_planes` of the feet (N, 6, 3) in contact (N, 6) at each step; the steps are
    fitted in groups that share a contact pattern."""
    contact = np.asarray(contact, dtype=bool)
    planes = np.full((len(feet), 3), np.nan)
    patterns = contact @ (1 << np.arange(contact.shape[1]))
    for pattern in np.unique(patterns):
        steps = np.flatnonzero(patterns == pattern)
        planes[steps] = support_planes(feet[steps][:, contact[steps[0]]])
    return planes


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
