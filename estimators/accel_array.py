"""The accelerometer array (sensors.accel_array): angular acceleration independent of the gyro, a
watch on the gyro, and a body rate to ride through its faults or to do without it.

Model (docs/estimators.md, "Accelerometer array"). An accelerometer at body point p_i, axes along
the body's, reads the specific force
    f_i = f_o + M p_i,    M = [alpha]x + W,    W = [omega]x [omega]x = omega omega^T - |omega|^2 I
with f_o the specific force at the body origin, alpha the angular acceleration and omega the body
rate (body frame). With the positions centred on their mean c, f_i - mean(f) = M (p_i - c): a least
squares fit gives M d for every direction d spanned by the p_i - c (all of M for a solid array,
two columns for the coplanar "quad"). alpha is the antisymmetric part of M - W on those columns:
given omega (from the gyro, or the rate this class carries), alpha is linear in the readings.
    planar array (x, y spanned):  alpha_z = (M_yx - M_xy) / 2,  alpha_x = M_zy - W_zy,
                                  alpha_y = -(M_zx - W_zx)
The diagonal of M reads -(omega_y^2 + omega_z^2) and -(omega_x^2 + omega_z^2): rate magnitudes
without their signs, second order (0.01 rad^2/s^2 at a walking 0.1 rad/s, below the fit's noise
over a stride), which is why this class integrates alpha instead.

`RateTracker` carries a body rate: integrated from alpha, pulled towards the gyro's (bias and
detected jumps removed) with the time constant TRACKING_TIME. Its residual gyro - rate is then the
gyro's own error at the time scale of TRACKING_TIME: a residual beyond JUMP_SIGMAS of its noise is
a jump of the gyro that the body's motion does not show (a bias step, or its end), and the jump is
taken into the gyro's `offset`. While the gyro is stuck, missing, or not used at all, the tracked
rate replaces it. The array's own offsets make a constant alpha error beta (2 mg over 16 cm:
0.17 rad/s^2); while the gyro is healthy the residual's mean is beta * TRACKING_TIME, and beta is
learnt from it over BETA_TIME. A foot's impact can drive the array's members beyond their range
(+-6 g on the default parts): the alpha of clipped readings is wrong by up to several rad/s^2 over
the impact's millisecond (0.2 to 0.6 rad/s of rate), so the gyro is then taken as it is; without
one, that alpha is still the best there is, and the feet correct what it leaves.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.model import spatial as rot

TRACKING_TIME = 0.02      # s: the tracked rate follows the gyro over this time
JUMP_SIGMAS = 8.0         # a residual this many of its standard deviations off is a gyro jump
JUMP_TIME = 0.005         # s a residual must stay beyond the limit, at one offset, to be a jump
BETA_TIME = 2.0           # s: the array's alpha offset is learnt over this time
CLIPPED = 0.999          # of the full scale: a reading there is clipped
MIN_SPAN = 1e-3           # m: directions along which the members spread less are not spanned


class AccelArrayFit:
    """Angular acceleration from one set of readings (module docstring)."""

    def __init__(self, positions: np.ndarray):
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        self.members = len(positions)
        centred = positions - positions.mean(axis=0)
        _, spread, directions = np.linalg.svd(centred, full_matrices=False)
        spanned = spread > MIN_SPAN
        self.span = directions[spanned]                 # (r, 3) orthonormal directions E^T
        if len(self.span) < 2:
            raise ValueError("an accelerometer array needs members spread along two directions at least")
        # f_i - mean(f) = M centred_i: least squares of M E from the coordinates along E.
        coordinates = centred @ self.span.T             # (n, r)
        self._fit = np.linalg.pinv(coordinates)         # (r, n): M E = (fit @ F)^T with F (n, 3) readings
        # alpha x e for each spanned e, as a linear map of alpha: B alpha = vec([alpha]x E).
        columns = [np.ravel(rot.skew(axis) @ self.span.T) for axis in np.eye(3)]
        self._solve = np.linalg.pinv(np.column_stack(columns))     # (3, 3 r)

    def alpha(self, readings: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """rad/s^2, body frame, from the members' readings (n, 3) and the body rate omega."""
        ME = (self._fit @ readings).T                   # (3, r)
        w = np.asarray(omega, dtype=float)
        W = np.outer(w, w) - (w @ w) * np.eye(3)
        return self._solve @ np.ravel(ME - W @ self.span.T)

    def noise_density(self, accel_noise_density: float) -> float:
        """rad/s^2/sqrt(Hz): the largest per-axis standard deviation of alpha per unit white noise
        of the accelerometers (each axis of each member `accel_noise_density`)."""
        # alpha is linear in the readings: alpha = solve @ vec((fit @ F)^T); its gain on each reading.
        gains = np.zeros((3, self.members * 3))
        for member in range(self.members):
            for axis in range(3):
                F = np.zeros((self.members, 3))
                F[member, axis] = 1.0
                gains[:, member * 3 + axis] = self._solve @ np.ravel((self._fit @ F).T)
        return float(accel_noise_density * math.sqrt(np.max(np.sum(gains**2, axis=1))))


class RateTracker:
    """The body rate carried through the array's angular acceleration (module docstring). Feed it
    every member reading (`add_member`); at each IMU sample either `follow` the gyro or `coast`
    without it. The array's readings of time t arrive after the IMU sample of t, so the gyro of t
    is compared with the rate at t once they are in: a jump found there is taken out of the
    readings from the next sample on."""

    def __init__(self, fit: AccelArrayFit, gyro_noise_density: float, accel_noise_density: float,
                 accel_offset_std: float, imu_rate: float, full_scale: float = math.inf):
        self.fit = fit
        self.full_scale = full_scale     # m/s^2: a reading this large is clipped, its alpha unknown
        self.rate = np.zeros(3)          # rad/s, body, at `_t`
        self.offset = np.zeros(3)        # rad/s, the gyro's detected jumps, taken out of its readings
        self.beta = np.zeros(3)          # rad/s^2, the array's learnt alpha offset
        self.jumps = 0
        self.jump_variance = 0.0         # (rad/s)^2 per axis: the error of the jumps taken since read
        self.alpha_density = fit.noise_density(accel_noise_density)       # rad/s^2/sqrt(Hz)
        self.beta_prior_std = fit.noise_density(accel_offset_std)         # rad/s^2 (a gain per unit offset)
        # The residual's noise: the gyro's white noise per sample, the tracked rate's own (the gyro
        # filtered over TRACKING_TIME, alpha integrated over it).
        gyro_sample = gyro_noise_density * math.sqrt(imu_rate)
        self.residual_std = math.sqrt(gyro_sample**2 * (1.0 + 1.0 / (2.0 * TRACKING_TIME * imu_rate))
                                      + self.alpha_density**2 * TRACKING_TIME / 2.0)
        self.sample_time = 1.0 / imu_rate
        self.jump_samples = max(1, round(JUMP_TIME * imu_rate))
        self.followed_time = 0.0         # s the gyro has been followed (beta learnt)
        self._readings = np.full((fit.members, 3), np.nan)
        self._reading_t: float | None = None
        self._alpha: np.ndarray | None = None       # at `_t`
        self._t: float | None = None
        self._pending: tuple[float, np.ndarray] | None = None    # a gyro body rate waiting for the array
        self._candidate: list[np.ndarray] = []      # residuals of a jump not confirmed yet
        self._checked_t: float | None = None        # s, the gyro sample checked last

    def add_member(self, t: float, index: int, accel: np.ndarray) -> None:
        if self._reading_t != t:
            self._readings[:] = np.nan
            self._reading_t = t
        if 0 <= index < self.fit.members:
            self._readings[index] = accel
        if np.isfinite(self._readings).all():
            clipped = np.max(np.abs(self._readings)) >= CLIPPED * self.full_scale
            self._advance(t, self.fit.alpha(self._readings, self.rate) - self.beta)
            self._readings[:] = np.nan
            if self._pending is not None and self._pending[0] == t:
                if clipped:         # a foot's impact beyond the range: the gyro is taken as it is
                    self.anchor(t, self._pending[1])
                else:
                    self._check(*self._pending)
                self._pending = None

    def _advance(self, t: float, alpha: np.ndarray | None) -> float:
        """Move the rate to t with the angular acceleration read at t (the interval's own: the
        readings sample the body's acceleration over the physics step that ends at t; on the
        testbed's 1 kHz steps the trapezoid rule leaves 0.3 rad/s errors after foot impacts, this
        one 4e-4), else with the last one held."""
        dt = 0.0 if self._t is None else max(t - self._t, 0.0)
        if alpha is not None:
            self._alpha = alpha
        if self._alpha is not None:
            self.rate += self._alpha * dt
        self._t = t
        return dt

    def beta_std(self) -> float:
        """rad/s^2: how well the array's alpha offset is known. Following the gyro, the offset's
        estimate settles with the time constant BETA_TIME from its prior, down to the residual's
        noise through that low-pass filter: residual_std / TRACKING_TIME * sqrt(dt / (2 BETA_TIME))."""
        floor = self.residual_std / TRACKING_TIME * math.sqrt(self.sample_time / (2.0 * BETA_TIME))
        return math.hypot(self.beta_prior_std * math.exp(-self.followed_time / BETA_TIME), floor)

    def follow(self, t: float, body_rate: np.ndarray) -> None:
        """The gyro's body rate at t (bias removed, jumps not), checked once the array's readings of
        t are in (or at the next sample, on the rate carried forward, if they never come)."""
        if self._pending is not None:
            self._advance(self._pending[0], None)
            self._check(*self._pending)
        self._pending = (t, np.array(body_rate, dtype=float))

    def _check(self, t: float, body_rate: np.ndarray) -> None:
        """The residual of the gyro at t against the rate: follow it, or count towards a jump: one
        beyond JUMP_SIGMAS that stays there for JUMP_TIME (an impact's transient does not)."""
        if self._checked_t is None or self._alpha is None:      # the first reading: the rate starts there
            self.anchor(t, body_rate)
            return
        dt = self._dt_since_check(t)
        residual = body_rate - self.offset - self.rate
        limit = JUMP_SIGMAS * self.residual_std
        if np.max(np.abs(residual)) > limit and (not self._candidate or np.max(np.abs(residual - self._candidate[0])) < limit):
            self._candidate.append(residual)
            if len(self._candidate) >= self.jump_samples:
                jump = np.mean(self._candidate, axis=0)
                self.offset += jump
                self.jumps += 1
                self.jump_variance += self.residual_std**2 / len(self._candidate)
                self._candidate.clear()
            return
        self._candidate.clear()
        if dt > 0:
            self.rate += residual * min(1.0, dt / TRACKING_TIME)
            self.beta -= residual / TRACKING_TIME * min(1.0, dt / BETA_TIME)
            self.followed_time += dt

    def _dt_since_check(self, t: float) -> float:
        last, self._checked_t = self._checked_t, t
        return 0.0 if last is None else max(t - last, 0.0)

    def anchor(self, t: float, body_rate: np.ndarray) -> None:
        """Restart the tracked rate from the gyro's body rate (bias removed, jumps not) at t."""
        self._pending = None
        self._checked_t = t
        self._candidate.clear()
        self.rate[:] = body_rate - self.offset
        self._t = t

    def coast(self, t: float) -> np.ndarray:
        """The tracked body rate at t, without the gyro (the last alpha held since the array's last
        readings)."""
        self._pending = None
        self._candidate.clear()
        if self._t is None or t <= self._t:
            return self.rate
        return self.rate + (0.0 if self._alpha is None else self._alpha * (t - self._t))

    def coasting_variance_rate(self, coasted: float) -> float:
        """(rad/s)^2 per s: how fast the tracked rate's error variance grows after `coasted` s
        without the gyro: alpha's white noise integrated, and the offset's error over the time."""
        return self.alpha_density**2 + 2.0 * self.beta_std()**2 * coasted
