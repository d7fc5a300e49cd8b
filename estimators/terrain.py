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
from numba import njit

from testbed.model import spatial as rot
from estimators.config import TerrainEstimatorConfig
from estimators.gating import chi2_quantile

# The filter's state and constants, fields by name (`TerrainFilter.record`).
TERRAIN_FILTER = np.dtype([("x", "f8", 3),             # a, b (slopes), height (m)
                           ("P", "f8", (3, 3)),        # covariance of x
                           ("rates", "f8", 3),         # random-walk variance rates of x, per s
                           ("gate", "f8")])            # NIS beyond which the filter restarts

MIN_FOOT_SPREAD = 0.03    # m: feet this close to a line (one side's three feet) define no reliable plane
YAW_TOLERANCE = 1e-3      # rad: heading change that refreshes the reported terrain angles


@dataclass(frozen=True)
class PlaneFit:
    coefficients: np.ndarray    # (3,) a, b, c of z = a x + b y + c
    covariance: np.ndarray      # (3, 3) of (a, b, c)


def smallest_spread(points: np.ndarray) -> float:
    """Standard deviation of the points' (x, y) across their best line: the smaller principal
    value of their 2x2 scatter, in closed form."""
    return _smallest_spread(np.ascontiguousarray(points, dtype=float))


@njit(cache=True)
def _smallest_spread(points: np.ndarray) -> float:
    count = points.shape[0]
    mx, my = points[:, 0].mean(), points[:, 1].mean()
    sxx = syy = sxy = 0.0
    for k in range(count):
        x, y = points[k, 0] - mx, points[k, 1] - my
        sxx += x * x
        syy += y * y
        sxy += x * y
    sxx, syy, sxy = sxx / count, syy / count, sxy / count
    half_trace, half_gap = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    return math.sqrt(max(0.0, half_trace - half_gap))


def fit_plane(points: np.ndarray, position_std: float) -> PlaneFit | None:
    """Least-squares plane z = a x + b y + c through n >= 3 points, or None if they are degenerate.

    The coefficient covariance is sigma^2 (A^T A)^-1 with sigma the larger of the assumed point
    noise and the residual standard error (non-coplanar feet: a step, rough ground).
    """
    points = np.ascontiguousarray(points, dtype=float)
    if len(points) < 3 or _smallest_spread(points) < MIN_FOOT_SPREAD:
        return None
    coefficients, covariance = _fit_plane(points, position_std)
    return PlaneFit(coefficients, covariance)


@njit(cache=True)
def _fit_plane(points: np.ndarray, position_std: float) -> tuple[np.ndarray, np.ndarray]:
    count = points.shape[0]
    design = np.ones((count, 3))
    design[:, 0] = points[:, 0]
    design[:, 1] = points[:, 1]
    heights = np.ascontiguousarray(points[:, 2])
    normal_matrix_inverse = np.linalg.inv(design.T @ design)
    coefficients = normal_matrix_inverse @ (design.T @ heights)
    variance = position_std**2
    if count > 3:
        residuals = heights - design @ coefficients
        variance = max(variance, (residuals @ residuals) / (count - 3))
    return coefficients, variance * normal_matrix_inverse


def slopes_and_height(fit: PlaneFit, foot_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(a, b, height) and its covariance: height of the origin above the contact plane, which lies
    one foot radius below the plane of the foot centres."""
    a, b, c = fit.coefficients
    s = math.sqrt(1.0 + a * a + b * b)
    height = -c / s + foot_radius
    jacobian = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [c * a / s**3, c * b / s**3, -1.0 / s]])
    return np.array([a, b, height]), jacobian @ fit.covariance @ jacobian.T


@njit(cache=True)
def plane_measurement(points: np.ndarray, position_std: float, foot_radius: float) -> tuple:
    """fit_plane then slopes_and_height in one compiled call (the filters' 200 Hz path):
    (valid, (a, b, height), covariance)."""
    if points.shape[0] < 3 or _smallest_spread(points) < MIN_FOOT_SPREAD:
        return False, np.zeros(3), np.zeros((3, 3))
    coefficients, covariance = _fit_plane(points, position_std)
    a, b, c = coefficients[0], coefficients[1], coefficients[2]
    s = math.sqrt(1.0 + a * a + b * b)
    jacobian = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [c * a / s**3, c * b / s**3, -1.0 / s]])
    return True, np.array([a, b, -c / s + foot_radius]), rot.matmul3(rot.matmul3(jacobian, covariance), jacobian.T)


@njit(cache=True)
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


@njit(cache=True)
def _kalman_update(record: np.ndarray, elapsed: float, z: np.ndarray, R: np.ndarray) -> bool:
    """Random-walk prediction over `elapsed` and update with z (covariance R) of the TERRAIN_FILTER
    record, in place; beyond the gate (or NaN) the filter restarts on z instead. Returns True on a
    restart."""
    f = record[0]
    prior = f.P + np.diag(f.rates * elapsed)
    innovation = z - f.x
    S_inverse = np.linalg.inv(prior + R)
    if not innovation @ S_inverse @ innovation <= f.gate:
        f.x[:] = z
        f.P[:] = R
        return True
    gain = rot.matmul3(prior, S_inverse)
    f.x[:] += rot.matvec3(gain, innovation)
    posterior = prior - rot.matmul3(gain, prior)
    f.P[:] = 0.5 * (posterior + posterior.T)
    return False


UPDATED, RESTARTED, NO_PLANE = 0, 1, 2     # what became of a measurement


@njit(cache=True)
def _update(record: np.ndarray, elapsed: float, z: np.ndarray, R: np.ndarray, first: bool) -> int:
    """`_kalman_update`, or on the `first` measurement x = z, P = R."""
    if first:
        f = record[0]
        f.x[:] = z
        f.P[:] = R
        return UPDATED
    return RESTARTED if _kalman_update(record, elapsed, z, R) else UPDATED


# Compiled: it runs at every encoder sample.
@njit(cache=True)
def _update_from_feet(feet: np.ndarray, down: np.ndarray, q: rot.Quaternion, position_std: float, foot_radius: float,
                      record: np.ndarray, elapsed: float, first: bool) -> int:
    """`_update` with the support plane of the feet `down`, levelled by q, if they define one."""
    count = 0
    for leg in range(feet.shape[0]):
        count += down[leg]
    if count < 3:
        return NO_PLANE
    stance = np.empty((count, 3))
    row = 0
    for leg in range(feet.shape[0]):
        if down[leg]:
            stance[row] = feet[leg]
            row += 1
    valid, z, R = plane_measurement(stance @ rot.to_matrix(q).T, position_std, foot_radius)
    if not valid:
        return NO_PLANE
    return _update(record, elapsed, z, R, first)


class TerrainFilter:
    """Random-walk Kalman filter on x = (a, b, height) of the support plane (gravity-aligned axes)."""

    def __init__(self, params: TerrainEstimatorConfig):
        self.record = np.zeros(1, dtype=TERRAIN_FILTER)
        fields = self.record[0]
        self.q = fields["rates"]
        self.q[:] = params.slope_random_walk**2, params.slope_random_walk**2, params.height_random_walk**2
        fields["gate"] = self.gate = chi2_quantile(params.change_gate_probability, 3)
        self.P = fields["P"]
        self._x = fields["x"]
        self.started = False
        self.t = -math.inf
        self.restarts = 0
        self._output: tuple | None = None
        self._output_yaw = 0.0

    @property
    def x(self) -> np.ndarray | None:
        """(a, b, height), None before the first plane."""
        return self._x if self.started else None

    def update(self, t: float, measurement: np.ndarray, covariance: np.ndarray) -> None:
        """A plane measurement (a, b, height) with its covariance."""
        self._updated(t, _update(self.record, self._elapsed(t), measurement, covariance, not self.started))

    def add_feet(self, t: float, feet: np.ndarray, down: np.ndarray, q: tuple, position_std: float,
                 foot_radius: float) -> None:
        """The support plane of the feet `down` (the (6,) mask of the rows of `feet`, (6, 3) in the
        body frame from O_b) levelled by the attitude q (world_from_body), if they define one."""
        self._updated(t, _update_from_feet(feet, down, q, position_std, foot_radius, self.record, self._elapsed(t),
                                           not self.started))

    def _elapsed(self, t: float) -> float:
        return max(0.0, t - self.t)

    def _updated(self, t: float, status: int) -> None:
        if status == NO_PLANE:
            return
        self.started = True
        self.t = t
        self.restarts += status == RESTARTED
        self._output = None

    def heading_output(self, yaw: float) -> tuple[float, float, float, np.ndarray, np.ndarray]:
        """(terrain_roll, terrain_pitch, body_height, covariance, growth) seen from heading `yaw`:
        the covariance at the last update and its growth per second since (`grown_covariance`).
        Recomputed only after an update or a heading change beyond YAW_TOLERANCE."""
        if self._output is None or abs(yaw - self._output_yaw) > YAW_TOLERANCE:
            self._output = _heading_output(self.x, self.P, self.q, yaw)
            self._output_yaw = yaw
        return self._output


@njit(cache=True)
def grown_covariance(covariance: np.ndarray, growth: np.ndarray, elapsed: float, tilt_cov: np.ndarray) -> np.ndarray:
    """The terrain output's covariance `elapsed` s after the last update (a new array).

    The plane was measured in axes aligned with the estimated gravity, so a body tilt error moves
    the terrain angles one for one (to first order): the tilt's 2x2 covariance is added.
    """
    grown = covariance + growth * elapsed
    grown[:2, :2] += tilt_cov
    return grown


@njit(cache=True)
def _heading_output(x: np.ndarray, P: np.ndarray, q: np.ndarray, yaw: float) -> tuple:
    roll, pitch, d_angles = heading_terrain_angles(x[0], x[1], yaw)
    jacobian = np.zeros((3, 3))
    jacobian[:2, :2] = d_angles
    jacobian[2, 2] = 1.0
    return (roll, pitch, x[2], rot.matmul3(rot.matmul3(jacobian, P), jacobian.T),
            rot.matmul3(rot.matmul3(jacobian, np.diag(q)), jacobian.T))
