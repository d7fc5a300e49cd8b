"""Support plane through the stance feet: terrain slope and body height from leg kinematics.

The stance-foot centres (forward kinematics of the encoder angles, eq. 2 of the paper) are
rotated into a gravity-aligned frame centred on the body origin, with the fused attitude, and a
plane z = a x + b y + c is fitted by least squares (as OpenSHC's walk plane). A three-state
random-walk Kalman filter on (a, b, height) holds the plane between fits, when fewer than three
feet are down or the encoders drop out, and restarts on the new plane when the support jumps
(a step edge). Terrain angles are reported in the heading frame, so they do not depend on the
unobservable yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.config import TerrainEstimatorConfig
from estimators.linalg import inverse3

MIN_FOOT_SPREAD = 0.03    # m: feet this close to a line (one side's three feet) define no reliable plane
YAW_TOLERANCE = 1e-3      # rad: heading change that refreshes the reported terrain angles


@dataclass(frozen=True)
class PlaneFit:
    coefficients: np.ndarray    # (3,) a, b, c of z = a x + b y + c
    covariance: np.ndarray      # (3, 3) of (a, b, c)


def smallest_spread(points: np.ndarray) -> float:
    """Standard deviation of the points' (x, y) across their best line: the smaller principal
    value of their 2x2 scatter, in closed form."""
    x, y = points[:, 0] - points[:, 0].mean(), points[:, 1] - points[:, 1].mean()
    sxx, syy, sxy = float(x @ x) / len(x), float(y @ y) / len(y), float(x @ y) / len(x)
    half_trace, half_gap = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    return math.sqrt(max(0.0, half_trace - half_gap))


def fit_plane(points: np.ndarray, position_std: float) -> PlaneFit | None:
    """Least-squares plane z = a x + b y + c through n >= 3 points, or None if they are degenerate.

    The coefficient covariance is sigma^2 (A^T A)^-1 with sigma the larger of the assumed point
    noise and the residual standard error (non-coplanar feet: a step, rough ground).
    """
    points = np.asarray(points, dtype=float)
    count = len(points)
    if count < 3 or smallest_spread(points) < MIN_FOOT_SPREAD:
        return None
    design = np.column_stack([points[:, 0], points[:, 1], np.ones(count)])
    normal_matrix_inverse = inverse3(design.T @ design)
    coefficients = normal_matrix_inverse @ (design.T @ points[:, 2])
    variance = position_std**2
    if count > 3:
        residuals = points[:, 2] - design @ coefficients
        variance = max(variance, float(residuals @ residuals) / (count - 3))
    return PlaneFit(coefficients, variance * normal_matrix_inverse)


def slopes_and_height(fit: PlaneFit, foot_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(a, b, height) and its covariance: height of the origin above the contact plane, which lies
    one foot radius below the plane of the foot centres."""
    a, b, c = fit.coefficients
    s = math.sqrt(1.0 + a * a + b * b)
    height = -c / s + foot_radius
    jacobian = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [c * a / s**3, c * b / s**3, -1.0 / s]])
    return np.array([a, b, height]), jacobian @ fit.covariance @ jacobian.T


def heading_terrain_angles(a: float, b: float, yaw: float) -> tuple[float, float, np.ndarray]:
    """Terrain (roll, pitch) of the plane z = a x + b y + c (gravity-aligned axes) seen from the
    heading `yaw`, and d(roll, pitch)/d(a, b).

    A body lying on the plane has its up axis along n ~ (-a_h, -b_h, 1) in the heading frame, and
    n = Ry(pitch) Rx(roll) e_z = (cos r sin p, -sin r, cos r cos p).
    """
    cy, sy = math.cos(yaw), math.sin(yaw)
    a_h, b_h = a * cy + b * sy, -a * sy + b * cy
    s2 = 1.0 + a_h * a_h + b_h * b_h
    s = math.sqrt(s2)
    root = math.sqrt(1.0 + a_h * a_h)
    roll = math.asin(b_h / s)
    pitch = math.atan(-a_h)
    d_heading = np.array([[-a_h * b_h / (s2 * root), root / s2], [-1.0 / (1.0 + a_h * a_h), 0.0]])
    return roll, pitch, d_heading @ np.array([[cy, sy], [-sy, cy]])


class TerrainFilter:
    """Random-walk Kalman filter on x = (a, b, height) of the support plane (gravity-aligned axes)."""

    def __init__(self, params: TerrainEstimatorConfig):
        self.x: np.ndarray | None = None
        self.P = np.zeros((3, 3))
        self.q = np.array([params.slope_random_walk**2, params.slope_random_walk**2, params.height_random_walk**2])
        self.gate = float(chi2.ppf(params.change_gate_probability, 3))
        self.t = -math.inf
        self.restarts = 0
        self._output: tuple | None = None
        self._output_yaw = 0.0

    def update(self, t: float, measurement: np.ndarray, covariance: np.ndarray) -> None:
        if self.x is None:
            self._restart(t, measurement, covariance)
            return
        prior = self.covariance_at(t)
        innovation = measurement - self.x
        innovation_cov = prior + covariance
        if innovation @ np.linalg.solve(innovation_cov, innovation) > self.gate:
            self.restarts += 1
            self._restart(t, measurement, covariance)
            return
        gain = np.linalg.solve(innovation_cov, prior).T    # prior S^-1, both symmetric
        self.x = self.x + gain @ innovation
        posterior = prior - gain @ prior
        self.P = 0.5 * (posterior + posterior.T)
        self.t = t
        self._output = None

    def _restart(self, t: float, measurement: np.ndarray, covariance: np.ndarray) -> None:
        self.x = measurement.copy()
        self.P = covariance.copy()
        self.t = t
        self._output = None

    def covariance_at(self, t: float) -> np.ndarray:
        covariance = self.P.copy()
        covariance.flat[::4] += self.q * max(0.0, t - self.t)
        return covariance

    def output(self, t: float, yaw: float, tilt_cov: np.ndarray | None) -> tuple[float, float, float, np.ndarray]:
        """(terrain_roll, terrain_pitch, body_height, covariance) at time t, heading `yaw`.

        The plane was measured in axes aligned with the estimated gravity, so a body tilt error
        moves the terrain angles one for one (to first order): its 2x2 covariance is added.
        """
        if self._output is None or abs(yaw - self._output_yaw) > YAW_TOLERANCE:
            self._output = self._heading_output(yaw)
            self._output_yaw = yaw
        roll, pitch, height, covariance, growth = self._output
        covariance = covariance + growth * max(0.0, t - self.t)
        if tilt_cov is not None:
            covariance[:2, :2] += tilt_cov
        return roll, pitch, height, covariance

    def _heading_output(self, yaw: float) -> tuple[float, float, float, np.ndarray, np.ndarray]:
        """Terrain angles for a heading, their covariance at the last update and its growth rate."""
        roll, pitch, d_angles = heading_terrain_angles(self.x[0], self.x[1], yaw)
        jacobian = np.zeros((3, 3))
        jacobian[:2, :2] = d_angles
        jacobian[2, 2] = 1.0
        return (roll, pitch, float(self.x[2]), jacobian @ self.P @ jacobian.T,
                jacobian @ np.diag(self.q) @ jacobian.T)
