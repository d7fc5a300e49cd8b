"""The fusion filters' compiled paths against the plain numpy formulas they replaced."""

import pickle
from unittest import mock

import numpy as np
from numba import njit

from testbed.model import spatial as rot
from estimators.base import Estimator
from estimators.config import TerrainEstimatorConfig
from estimators.ekf import FOOT0, _foot_nis
from estimators.fusion import output_covariances
from estimators.leg_odometry import StanceTracker
from estimators.linalg import product3, transposed_product3
from estimators.registry import make_estimator
from estimators.terrain import TerrainFilter, plane_measurement
from sensors.samples import ImuSample

TERRAIN = TerrainEstimatorConfig(slope_random_walk=0.02, height_random_walk=0.01, change_gate_probability=0.9999)


def random_covariance(rng: np.random.Generator, size: int, scale: float) -> np.ndarray:
    root = rng.normal(0.0, scale, (size, size))
    return root @ root.T


def test_foot_gate_nis_matches_a_linear_solve():
    rng = np.random.default_rng(0)
    for _ in range(200):
        P = random_covariance(rng, 32, 1e-3)
        leg, variance = rng.integers(6), rng.uniform(1e-8, 1e-6)
        y = rng.normal(0.0, 1e-3, 3)
        b = FOOT0 + 3 * leg
        expected = y @ np.linalg.solve(P[b:b + 3, b:b + 3] + variance * np.eye(3), y)
        assert abs(_foot_nis(P, b, variance, y) - expected) <= 1e-12 * expected


@njit
def _compiled_products(a, b, v):
    return (a @ b, a.T @ b, a @ b.T, a.T @ b.T), a.T @ v


def _awkward_values(rng, shape):
    """Magnitudes over 13 decades, with zeros of both signs."""
    values = rng.normal(size=shape) * 10.0 ** rng.integers(-10, 3, shape)
    draw = rng.random(shape)
    values[draw < 0.15] = 0.0
    values[(draw >= 0.15) & (draw < 0.25)] = -0.0
    return values


def test_3x3_products_equal_numpy_and_numba_bit_for_bit():
    rng = np.random.default_rng(2)
    for _ in range(20000):
        a, b, v = _awkward_values(rng, (3, 3)), _awkward_values(rng, (3, 3)), _awkward_values(rng, 3)
        numba_products, numba_vector = _compiled_products(a, b, v)
        for left, right, numba_product in zip((a, a.T, a, a.T), (b, b, b.T, b.T), numba_products):
            for expected in (left @ right, numba_product):
                assert product3(left, right).tobytes() == expected.tobytes()
        for expected in (a.T @ v, numba_vector):
            assert transposed_product3(a.T, v).tobytes() == expected.tobytes()


def test_output_covariances_equal_the_numpy_products_bit_for_bit():
    rng = np.random.default_rng(1)
    P, terrain_cov, growth = random_covariance(rng, 32, 0.1), random_covariance(rng, 3, 0.1), np.diag([1.0, 2.0, 3.0])
    bias = rng.normal(0.0, 0.01, 3)
    attitude_cov, bias_copy, bias_cov, grown = output_covariances(P, bias, 0.2, -0.3, terrain_cov, growth, 0.004)
    euler = rot.euler_jacobian(0.2, -0.3)
    expected_attitude = euler @ P[0:3, 0:3] @ euler.T
    expected_terrain = terrain_cov + growth * 0.004
    expected_terrain[:2, :2] += expected_attitude[:2, :2]
    assert np.array_equal(attitude_cov, expected_attitude)
    assert np.array_equal(bias_copy, bias) and bias_copy is not bias
    assert np.array_equal(bias_cov, P[3:6, 3:6])
    assert np.array_equal(grown, expected_terrain)


def test_reading_matches_the_feet_and_their_masks(geometry):
    rng = np.random.default_rng(2)
    tracker = StanceTracker(geometry, origin=np.array([0.01, -0.02, 0.03]))
    tracker.contact[:] = [True, True, False, True, True, True]
    tracker.tracked[:] = [True, False, False, True, False, True]
    positions = rng.uniform(-0.3, 0.3, 18)
    positions[15] = np.nan                         # the last leg read badly
    reading = tracker.read(positions, None)
    feet = tracker.feet(positions)
    measurable = tracker.contact & np.isfinite(feet).all(axis=1)
    assert np.array_equal(reading.feet, feet, equal_nan=True)
    assert np.array_equal(reading.measured, feet - tracker.origin, equal_nan=True)
    assert np.array_equal(reading.measurable, measurable)
    assert list(reading.tracked) == [0, 3]
    assert list(reading.new) == [1, 4]


def test_rolling_moves_only_the_tracked_feet(geometry):
    tracker = StanceTracker(geometry)
    tracker.contact[:] = True
    tracker.tracked[:] = [True, False, True, False, True, False]
    filter_feet = np.zeros((6, 3))
    rolling = (filter_feet, np.array([0.01, -0.02, 0.0]), (0.0, 0.0, 1.0), 0.01)
    positions = np.zeros(18)
    tracker.read(positions, rolling)               # the first reading only remembers the angles
    assert not filter_feet.any()
    tracker.read(positions + 0.01, rolling)
    assert np.all(filter_feet[[0, 2, 4]].any(axis=1)) and not filter_feet[[1, 3, 5]].any()


def test_support_plane_from_feet_equals_the_plane_measurement_update():
    rng = np.random.default_rng(3)
    q = rot.quaternion_from_euler(0.05, -0.1, 0.4)
    by_feet, by_measurement = TerrainFilter(TERRAIN), TerrainFilter(TERRAIN)
    for k in range(20):
        feet = np.column_stack([rng.uniform(-0.2, 0.2, 6), rng.uniform(-0.2, 0.2, 6), rng.normal(-0.1, 0.002, 6)])
        down = rng.random(6) < 0.8
        by_feet.add_feet(0.005 * k, feet, down, q, 3e-4, 0.01)
        valid, measurement, covariance = plane_measurement(feet[down] @ rot.to_matrix(q).T, 3e-4, 0.01)
        if valid:
            by_measurement.update(0.005 * k, measurement, covariance)
        assert np.array_equal(by_feet.x, by_measurement.x) and np.array_equal(by_feet.P, by_measurement.P)
        assert (by_feet.t, by_feet.restarts) == (by_measurement.t, by_measurement.restarts)


def test_fusion_imu_path_equals_the_base_class_path(runs):
    """FusionEstimator.update hands IMU samples to its kernel unchecked; Estimator.update checks
    them first (None for a non-finite reading). Same estimates, bad readings included."""
    samples = [s for s in runs.samples(0) if s.t < 1.0]
    for k in range(300, 310):                      # bad readings once the filter runs
        if isinstance(samples[k], ImuSample):
            samples[k] = ImuSample(samples[k].t, np.array([np.nan, 1.0, np.inf]), samples[k].gyro)
    for name in ("ekf", "ukf"):
        fast, checked = make_estimator(name, runs.config), make_estimator(name, runs.config)
        for sample in samples:
            a, b = fast.update(sample), Estimator.update(checked, sample)
            assert (a is None) == (b is None)
            if a is not None:
                assert all(np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
                           for x, y in zip(vars(a).values(), vars(b).values()))


def test_fusion_imu_path_takes_arrays_that_numba_boxed(runs):
    """The sensors' readings come out of cached compiled code, whose float64 arrays carry a dtype
    object of their own (unpickled from the cache): they take the direct path too (the base
    class's checks are not called)."""
    unpickled = pickle.loads(pickle.dumps(np.dtype(np.float64)))
    assert unpickled is not np.dtype(np.float64)
    samples = [s for s in runs.samples(0) if s.t < 0.2]
    ekf = make_estimator("ekf", runs.config)
    ekf.update(samples[0])
    with mock.patch.object(Estimator, "_to_body", side_effect=AssertionError("base class path")):
        for sample in samples[1:]:
            if isinstance(sample, ImuSample):
                ekf.update(ImuSample(sample.t, np.array(sample.accel, dtype=unpickled),
                                     np.array(sample.gyro, dtype=unpickled)))
