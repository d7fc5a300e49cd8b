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
    """The metrics of one run (see the module docstring); keys METRIC_KEYS, values float or None."""
    scored = estimates.t >= truth_t[0] + skip
    if not scored.any():
        raise ValueError(f"no estimate after the first {skip} s")
    true_rpy = roll_pitch_yaw(truth_at(estimates.t[scored], truth_t, truth_rotation))
    error = np.column_stack([wrap(estimates.roll[scored] - true_rpy[:, 0]),
                             wrap(estimates.pitch[scored] - true_rpy[:, 1])])
    tilt = angle_between(up_in_body(estimates.roll[scored], estimates.pitch[scored]),
                         up_in_body(true_rpy[:, 0], true_rpy[:, 1]))
    metrics = {
        "roll_rmse_deg": float(np.degrees(rms(error[:, 0]))),
        "pitch_rmse_deg": float(np.degrees(rms(error[:, 1]))),
        "tilt_error_max_deg": float(np.degrees(tilt.max())),
        "slope_error_deg": None,
        "height_est_rmse_m": None,
        "anees_tilt": None,
    }
    if estimates.tilt_cov is not None:
        metrics["anees_tilt"] = float(np.mean(nees_2d(error, estimates.tilt_cov[scored])))
    if terrain_truth is not None and estimates.terrain_roll is not None:
        metrics.update(terrain_metrics(estimates, terrain_truth, truth_t[0] + skip, truth_t[0] + slope_settle))
    return metrics


def terrain_metrics(estimates: EstimateArrays, truth: TerrainTruth, height_from: float, slope_from: float) -> dict:
    def true_at(values):
        return np.interp(estimates.t, truth.t, values)

    slope_window = estimates.t >= slope_from
    estimated_normal = up_in_body(estimates.terrain_roll, estimates.terrain_pitch)
    true_normal = up_in_body(true_at(truth.terrain_roll), true_at(truth.terrain_pitch))
    slope_error = angle_between(estimated_normal, true_normal)[slope_window]
    slope_error = slope_error[np.isfinite(slope_error)]
    height_error = (estimates.body_height - true_at(truth.body_height))[estimates.t >= height_from]
    height_rms = rms(height_error)
    return {"slope_error_deg": float(np.degrees(slope_error.max())) if len(slope_error) else None,
            "height_est_rmse_m": height_rms}


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
