"""The estimator interface shared by the live run and offline replay.

An estimator consumes timestamped sensor samples, in time order, one at a time, and returns an
`Estimate` after every IMU sample that changed its state. Encoder and foot samples are absorbed
silently and show up in the next estimate. Estimators never see ground truth, hold no random
state, and are deterministic: the same samples in the same order give bit-identical estimates,
which is what lets a replay reproduce a recorded run exactly.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import islice
from typing import ClassVar

import numpy as np

from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample


@dataclass
class Estimate:
    """State of an estimator at time t. Read-only by convention: do not modify it or its arrays.

    Attitude is world_from_body with a z-up world; roll, pitch and yaw are ZYX Euler angles
    (R = Rz(yaw) Ry(pitch) Rx(roll), scipy's `as_euler("ZYX")` reversed). Roll and pitch are with
    respect to gravity; yaw is relative to the start heading and unobservable (its variance grows).
    Position and velocity (full-state estimators only; None from attitude-only ones) are in the
    start frame: origin at the body origin at start, x along the start heading, z up; like yaw they
    are dead-reckoned, their variances growing with time and distance.
    Terrain roll and pitch are those of a body lying flat on the support plane with the robot's
    current heading; body height is the distance from the body origin O_b to that plane (the
    plane through the stance feet's contact points).

    Not a frozen dataclass: a frozen one's __init__ sets each field through object.__setattr__,
    several times slower, and the fusion filters make one per IMU sample.
    """
    t: float                                   # s
    quaternion: np.ndarray                     # (4,) world_from_body, scipy order x, y, z, w
    roll: float                                # rad
    pitch: float                               # rad
    yaw: float                                 # rad
    attitude_cov: np.ndarray | None = None     # (3, 3) covariance of the (roll, pitch, yaw) errors, rad^2
    gyro_bias: np.ndarray | None = None        # (3,) rad/s, body frame
    gyro_bias_cov: np.ndarray | None = None    # (3, 3) (rad/s)^2
    terrain_roll: float | None = None          # rad
    terrain_pitch: float | None = None         # rad
    body_height: float | None = None           # m
    terrain_cov: np.ndarray | None = None      # (3, 3) covariance of (terrain_roll, terrain_pitch, body_height)
    position: np.ndarray | None = None         # (3,) m, body origin in the start frame (see below)
    velocity: np.ndarray | None = None         # (3,) m/s, body origin's, start frame
    position_cov: np.ndarray | None = None     # (3, 3) m^2
    velocity_cov: np.ndarray | None = None     # (3, 3) (m/s)^2


class Estimator(abc.ABC):
    """Base class of every estimator, built-in or a user's plugin.

    A subclass implements `update(sample) -> Estimate | None` (sample: `ImuSample`,
    `EncoderSample`, `FootSample` or `AccelSample`; samples of other types must be ignored) or,
    like the built-ins, `_update_imu` and the optional `_update_encoders` / `_update_feet` hooks,
    with IMU vectors already rotated into the body frame. A class method `from_config(config)`
    receives the run's `Config` when present; otherwise the class is built with no arguments.
    """

    name: ClassVar[str] = ""
    # The sample classes `update` reads; the live run and replay give it only those (None: all).
    sample_types: ClassVar[tuple[type, ...] | None] = None
    _body_from_imu: np.ndarray | None = None

    def __init__(self, imu_rotation: np.ndarray | None = None):
        rotation = np.eye(3) if imu_rotation is None else np.asarray(imu_rotation, dtype=float)
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-9) \
                or np.linalg.det(rotation) < 0:
            raise ValueError("imu_rotation must be a 3x3 rotation matrix (body_from_imu)")
        self._body_from_imu = None if np.array_equal(rotation, np.eye(3)) else rotation

    def update(self, sample: Sample) -> Estimate | None:
        if isinstance(sample, ImuSample):
            return self._update_imu(sample.t, self._to_body(sample.gyro), self._to_body(sample.accel))
        if isinstance(sample, EncoderSample):
            self._update_encoders(sample)
        elif isinstance(sample, FootSample):
            self._update_feet(sample)
        return None

    def update_batch(self, samples: Iterable[Sample]) -> list[Estimate]:
        """The estimates of time-ordered `samples`, exactly as `update` gives them one at a time.
        An estimator whose library has a compiled batch loop overrides it with that loop."""
        return [estimate for estimate in map(self.update, samples) if estimate is not None]

    def batch_estimates(self, samples: Sequence[Sample]) -> Estimates:
        """`update_batch`'s estimates as `Estimates` (offline replay calls this); a filter whose
        compiled loop writes its estimates as rows overrides it to keep them as rows."""
        estimates = Estimates()
        estimates.add(self.update_batch(samples))
        return estimates

    def _to_body(self, vector: np.ndarray) -> np.ndarray | None:
        """The IMU vector in the body frame, or None when it is not a finite 3-vector."""
        vector = np.asarray(vector, dtype=float)
        # The sum is finite only if every component is: one scalar test instead of an array one.
        if vector.shape != (3,) or not math.isfinite(vector[0] + vector[1] + vector[2]):
            return None
        return vector if self._body_from_imu is None else self._body_from_imu @ vector

    def _update_imu(self, t: float, gyro: np.ndarray | None, accel: np.ndarray | None) -> Estimate | None:
        """Body-frame gyro (rad/s) and specific force (m/s^2); None for an invalid reading."""
        raise NotImplementedError(f"{type(self).__name__} implements neither update nor _update_imu")

    def _update_encoders(self, sample: EncoderSample) -> None:
        """Attitude-only estimators ignore the legs."""

    def _update_feet(self, sample: FootSample) -> None:
        """Attitude-only estimators ignore the legs."""


# The per-sample fields of a run of estimates whose other fields are the same (`EstimateRows`):
# attitude (quaternion x, y, z, w; rad) and pose (body origin, start frame: m, m/s).
ESTIMATE_ROWS = np.dtype([("quaternion", "f8", 4), ("roll", "f8"), ("pitch", "f8"), ("yaw", "f8"),
                          ("position", "f8", 3), ("velocity", "f8", 3)])
ROW_FIELDS = frozenset(ESTIMATE_ROWS.names)
# The fields an `EstimateRows` shares among its estimates, in Estimate's order.
STEP_FIELDS = ("attitude_cov", "gyro_bias", "gyro_bias_cov", "terrain_roll", "terrain_pitch", "body_height",
               "terrain_cov")
POSE_COVARIANCE_FIELDS = ("position_cov", "velocity_cov")
SHARED_FIELDS = STEP_FIELDS + POSE_COVARIANCE_FIELDS


@dataclass
class EstimateRows:
    """Estimates held as columns: at the times `t[first:stop]`, with the attitudes and poses of
    the ESTIMATE_ROWS `rows[first:stop]` (`t` and `rows` may be a batch's, which other
    EstimateRows share), and the same values of the other fields (`step`: STEP_FIELDS;
    `pose_covariances`: POSE_COVARIANCE_FIELDS)."""
    t: np.ndarray                # (N,) s
    rows: np.ndarray             # (N,) ESTIMATE_ROWS
    first: int
    stop: int
    step: tuple
    pose_covariances: tuple

    def __len__(self) -> int:
        return self.stop - self.first

    def estimates(self) -> list[Estimate]:
        """The Estimate objects; their arrays are views of `rows` and the shared arrays."""
        rows, step, covariances = self.rows[self.first:self.stop], self.step, self.pose_covariances
        return [Estimate(t, quaternion, roll, pitch, yaw, *step, position, velocity, *covariances)
                for t, quaternion, roll, pitch, yaw, position, velocity
                in zip(self.t[self.first:self.stop].tolist(), rows["quaternion"], rows["roll"].tolist(),
                       rows["pitch"].tolist(), rows["yaw"].tolist(), rows["position"], rows["velocity"])]


class Estimates(Sequence[Estimate]):
    """Estimates in time order, held in parts: lists of Estimate objects and `EstimateRows`, whose
    objects are built when an estimate is first read (and then kept), so that columns can be taken
    from the rows without them (`estimators.scoring.estimate_arrays`)."""

    def __init__(self) -> None:
        self.parts: list[list[Estimate] | EstimateRows] = []
        self._length = 0
        self._objects: list[Estimate] | None = None

    def add(self, estimates: list[Estimate] | EstimateRows | Estimates) -> None:
        """Append estimates (a list, rows, or those of other Estimates)."""
        count = len(estimates)
        if not count:
            return
        if self._objects is not None:
            self._objects += estimates.estimates() if isinstance(estimates, EstimateRows) else list(estimates)
        self._length += count
        if isinstance(estimates, Estimates):
            self.parts += [list(part) if isinstance(part, list) else part for part in estimates.parts]
        elif isinstance(estimates, EstimateRows):
            self.parts.append(estimates)
        elif self.parts and isinstance(self.parts[-1], list):
            self.parts[-1] += estimates
        else:
            self.parts.append(list(estimates))

    def append(self, estimate: Estimate) -> None:
        self.add([estimate])

    def objects(self) -> list[Estimate]:
        """The estimates as Estimate objects, built once."""
        if self._objects is None:
            self._objects = [estimate for part in self.parts
                             for estimate in (part if isinstance(part, list) else part.estimates())]
        return self._objects

    def __len__(self) -> int:
        return self._length

    def __getitem__(self, index):
        return self.objects()[index]

    def __iter__(self) -> Iterator[Estimate]:
        return iter(self.objects())

    def __eq__(self, other) -> bool:
        return self.objects() == list(other) if isinstance(other, Sequence) else NotImplemented

    __hash__ = None

    def __repr__(self) -> str:
        return f"Estimates({len(self)} estimates)"


def imu_rotation(config) -> np.ndarray:
    """body_from_imu of the configured IMU mounting (sensor geometry is known; truth is not)."""
    return np.array(config.sensors.imu.body_from_sensor)


def imu_position(config) -> np.ndarray:
    """m, body frame: the IMU's accelerometer point."""
    return np.array(config.sensors.imu.position, dtype=float)


def stacked_readings(samples: Sequence[ImuSample]) -> tuple[np.ndarray, np.ndarray] | None:
    """(gyro (N, 3), accel (N, 3)) of the IMU samples' readings as they are (sensor frame, not
    checked for finite values), or None when a reading is not a 3-vector: the input of an
    estimator's compiled batch loop."""
    try:
        gyro, accel = (np.array([getattr(sample, name) for sample in samples], dtype=float)
                       for name in ("gyro", "accel"))
    except (ValueError, TypeError):
        return None
    return (gyro, accel) if gyro.shape == accel.shape == (len(samples), 3) else None


def samples_for(estimator: Estimator, samples: Iterable[Sample]) -> Iterable[Sample]:
    """The samples of the classes the estimator reads (`Estimator.sample_types`; all when None)."""
    types = estimator.sample_types
    return samples if types is None else (sample for sample in samples if isinstance(sample, types))


def run_estimator(estimator: Estimator, samples: Iterable[Sample], batch: int = 4096) -> list[Estimate]:
    """Feed time-ordered samples to an estimator, `batch` at a time through `update_batch`, and
    collect its estimates (offline replay)."""
    estimates: list[Estimate] = []
    for batch_estimates in estimate_batches(estimator, samples, batch):
        estimates += batch_estimates
    return estimates


def estimate_batches(estimator: Estimator, samples: Iterable[Sample], batch: int = 4096) -> Iterator[Estimates]:
    """`run_estimator`'s estimates, `batch_estimates` by `batch_estimates`."""
    wanted = iter(samples_for(estimator, samples))
    while chunk := list(islice(wanted, batch)):
        yield estimator.batch_estimates(chunk)
