"""The fusion filters' compiled paths against the readable functions and numpy formulas they speed up."""

import math
import pickle
from unittest import mock

import numpy as np
import pytest

from testbed.model import spatial as rot
from estimators.base import Estimator
from estimators.config import TerrainEstimatorConfig
from estimators.ekf import FEET_UPDATE, correct_feet, feet_correction
from estimators.fusion import (ACCEL_ERRORS, ERROR_DIM, FOOT0, MISSING, NO_TERRAIN, NOMINAL, OUTPUT_SETTINGS,
                               POSITION, TILT_SUMS, BiasStepDetector, NominalState, StepState, TerrainGrowth,
                               current_pose, drift_statistic, foot_nis, ground_normal_in_body, horizontal_basis,
                               imu_sample_and_pose, inject, output_covariances, pose_covariances, roll_feet, sink_feet,
                               step_covariances)
from estimators.preintegration import Preintegration, imu_sample
from estimators.leg_odometry import StanceTracker
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
        assert abs(foot_nis(P, b, variance, y) - expected) <= 1e-12 * expected


def random_nominal(rng: np.random.Generator) -> np.ndarray:
    nominal = np.zeros(1, dtype=NOMINAL)
    for name in NOMINAL.names:
        nominal[0][name] = rng.normal(0.0, 0.2, nominal[0][name].shape)
    return nominal


@pytest.mark.parametrize("consider", [(0, 0), (ACCEL_ERRORS.start, ACCEL_ERRORS.stop)])
def test_compiled_feet_update_equals_the_readable_one(consider):
    """correct_feet against feet_correction run as Python, then inject and BiasStepDetector.add."""
    rng = np.random.default_rng(5)
    for trial in range(50):
        P = random_covariance(rng, ERROR_DIM, 1e-2) + 1e-6 * np.eye(ERROR_DIM)
        nominal, q = random_nominal(rng), rot.quaternion_from_euler(*rng.normal(0.0, 0.3, 3))
        x = nominal[0]
        state = NominalState(q, x["bias"].copy(), x["velocity"].copy(), x["accel_bias"].copy(), x["feet"].copy(),
                             x["accel_cross"].copy(), x["position"].copy())
        legs = rng.permutation(6)[:rng.integers(1, 7)]
        # Mostly small innovations, some beyond the gate, and tilts large enough to be reset.
        measured = state.feet[legs] + rng.normal(0.0, 0.01, (len(legs), 3)) * rng.choice([1.0, 30.0], (len(legs), 1))
        settings = np.array([(1e-4, 11.3, *consider)], dtype=FEET_UPDATE)
        detector = BiasStepDetector(1.0, 0.99, 0.005, 0.014)
        P_compiled = P.copy()
        accepted, dx, tilt_cov = feet_correction(P, measured, state.feet, legs, 1e-4, 11.3, *consider)
        if accepted.any():
            state = inject(state, dx)
            detector.add(dx[0:3], tilt_cov)
        sums = np.zeros(1, dtype=TILT_SUMS)
        compiled_accepted, compiled_q = correct_feet(P_compiled, measured, legs, settings, nominal, q, sums)
        np.testing.assert_array_equal(compiled_accepted, accepted)
        tolerance = {"rtol": 1e-9, "atol": 1e-15}
        np.testing.assert_allclose(P_compiled, P, **tolerance)
        np.testing.assert_allclose(compiled_q, state.q, **tolerance)
        for name in NOMINAL.names:
            np.testing.assert_allclose(x[name], getattr(state, name), **tolerance)
        np.testing.assert_allclose(sums[0]["correction"], detector.sums[0]["correction"], **tolerance)
        np.testing.assert_allclose(sums[0]["covariance"], detector.sums[0]["covariance"], **tolerance)
        if accepted.any():
            start, stop = consider
            assert not dx[start:stop].any()      # consider states keep their value


def test_output_covariances_equal_the_numpy_products():
    rng = np.random.default_rng(1)
    P, terrain_cov, growth = random_covariance(rng, 32, 0.1), random_covariance(rng, 3, 0.1), np.diag([1.0, 2.0, 3.0])
    bias = rng.normal(0.0, 0.01, 3)
    attitude_cov, bias_copy, bias_cov, grown = output_covariances(P, bias, 0.2, -0.3, terrain_cov, growth, 0.004)
    euler = rot.euler_jacobian(0.2, -0.3)
    expected_attitude = euler @ P[0:3, 0:3] @ euler.T
    expected_terrain = terrain_cov + growth * 0.004
    expected_terrain[:2, :2] += expected_attitude[:2, :2]
    np.testing.assert_allclose(attitude_cov, expected_attitude, rtol=1e-12, atol=1e-15)
    assert np.array_equal(bias_copy, bias) and bias_copy is not bias
    assert np.array_equal(bias_cov, P[3:6, 3:6])
    np.testing.assert_allclose(grown, expected_terrain, rtol=1e-12, atol=1e-15)


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
    np.testing.assert_allclose(reading.feet, feet, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(reading.measured, feet - tracker.origin, rtol=1e-12, atol=1e-15)
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


def test_support_plane_from_feet_matches_the_plane_measurement_update():
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
        if by_feet.x is None:
            assert by_measurement.x is None
            continue
        np.testing.assert_allclose(by_feet.x, by_measurement.x, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(by_feet.P, by_measurement.P, rtol=1e-9, atol=1e-18)
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


def test_pose_covariances_equal_the_numpy_products():
    """The covariances J P J^T of the body origin's position and velocity (fusion.pose_covariances)."""
    rng = np.random.default_rng(3)
    P = random_covariance(rng, ERROR_DIM, 0.1)
    q = rot.quaternion_from_euler(0.2, -0.1, 1.3)
    velocity, rate, lever = (rng.normal(0.0, 0.5, 3) for _ in range(3))
    position_cov, velocity_cov = pose_covariances(P, q, velocity, rate, lever)
    R = rot.to_matrix(q)
    body_velocity = velocity - np.cross(rate, lever)
    J_position = np.zeros((3, ERROR_DIM))
    J_position[:, POSITION] = np.eye(3)
    J_position[:, 0:3] = R @ rot.skew(lever)
    J_velocity = np.zeros((3, ERROR_DIM))
    J_velocity[:, 6:9] = R
    J_velocity[:, 0:3] = -R @ rot.skew(body_velocity)
    np.testing.assert_allclose(position_cov, J_position @ P @ J_position.T, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(velocity_cov, J_velocity @ P @ J_velocity.T, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("scale_error", [0.0, 0.0125])
@pytest.mark.parametrize("with_terrain", [False, True])
def test_step_covariances_are_the_output_and_pose_covariances(scale_error, with_terrain):
    """fusion.step_covariances against output_covariances and pose_covariances, the position's
    widened by the outer product of the scale error along the horizontal distance walked."""
    rng = np.random.default_rng(8)
    P = random_covariance(rng, ERROR_DIM, 0.1)
    q = rot.quaternion_from_euler(0.1, 0.2, -2.0)
    velocity, bias, position, start, gyro, lever = (rng.normal(0.0, 0.5, 3) for _ in range(6))
    terrain = TerrainGrowth(random_covariance(rng, 3, 0.1), np.diag([1.0, 2.0, 3.0]), 0.02) if with_terrain \
        else NO_TERRAIN
    settings = np.zeros(1, dtype=OUTPUT_SETTINGS)
    settings[0] = lever, scale_error
    outputs = step_covariances(P, StepState(q, velocity, bias, position, start, gyro), settings, 0.3, -0.2, terrain)
    expected = [*output_covariances(P, bias, 0.3, -0.2, terrain.covariance, terrain.rate, terrain.elapsed),
                *pose_covariances(P, q, velocity, gyro - bias, lever)]
    walked = (position - start) * [1.0, 1.0, 0.0]
    expected[4] = expected[4] + np.outer(scale_error * walked, scale_error * walked)
    for output, value in zip(outputs, expected, strict=True):
        np.testing.assert_allclose(output, value, rtol=1e-12, atol=1e-15)
    assert outputs[1] is not bias


def test_rolling_feet_move_and_widen_only_the_rolled_feet():
    rng = np.random.default_rng(4)
    P = random_covariance(rng, ERROR_DIM, 0.1)
    feet = rng.normal(0.0, 0.2, (6, 3))
    rolled = np.zeros((6, 3))
    rolled[[1, 4]] = rng.normal(0.0, 1e-3, (2, 3))
    P_after, feet_after = P.copy(), feet.copy()
    roll_feet(P_after, feet_after, rolled, 0.25, 0.5)
    np.testing.assert_allclose(feet_after, feet + 0.25 * rolled, rtol=1e-12, atol=1e-15)
    grown = np.zeros(ERROR_DIM)
    grown[FOOT0:FOOT0 + 18] = (0.5 * rolled.ravel())**2
    np.testing.assert_allclose(P_after, P + np.diag(grown), rtol=1e-12, atol=1e-15)


def test_loaded_feet_widen_only_the_tracked_feet_along_up_and_across_it():
    rng = np.random.default_rng(8)
    P = random_covariance(rng, ERROR_DIM, 0.1)
    up = rng.normal(size=3)
    up /= np.linalg.norm(up)
    loads, previous = rng.uniform(0.0, 10.0, 6), rng.uniform(0.0, 10.0, 6)
    load_change = loads - previous
    P_after = P.copy()
    sink_feet(P_after, np.array([0, 3, 5, 1]), loads, np.where(np.arange(6) == 1, np.nan, previous), tuple(up),
              1e-4, 4e-4)
    expected = P.copy()
    across = np.eye(3) - np.outer(up, up)
    for leg in (0, 3, 5):
        block = slice(FOOT0 + 3 * leg, FOOT0 + 3 * leg + 3)
        expected[block, block] += load_change[leg]**2 * (1e-8 * np.outer(up, up) + 16e-8 * across)
    np.testing.assert_allclose(P_after, expected, rtol=1e-12, atol=1e-15)
    # Along up only the sinking adds; across it only the sliding.
    growth = (P_after - P)[FOOT0:FOOT0 + 3, FOOT0:FOOT0 + 3]
    side = np.cross(up, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    np.testing.assert_allclose([up @ growth @ up, side @ growth @ side],
                               [(1e-4 * load_change[0])**2, (4e-4 * load_change[0])**2], rtol=1e-9)


def test_drift_statistic_equals_the_numpy_products():
    rng = np.random.default_rng(6)
    for _ in range(20):
        sums = np.zeros(1, dtype=TILT_SUMS)
        sums[0]["correction"] = rng.normal(0.0, 1e-3, 3)
        sums[0]["covariance"] = random_covariance(rng, 3, 1e-6)
        q = rot.quaternion_from_euler(*rng.normal(0.0, 0.4, 3))
        basis = horizontal_basis(np.array(rot.up_in_body(q)))
        np.testing.assert_allclose(basis @ basis.T, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(basis @ np.array(rot.up_in_body(q)), np.zeros(2), atol=1e-12)
        drift = basis @ sums[0]["correction"]
        covariance = basis @ sums[0]["covariance"] @ basis.T
        statistic, norm = drift_statistic(sums, q)
        np.testing.assert_allclose(statistic, drift @ np.linalg.solve(covariance, drift), rtol=1e-9)
        np.testing.assert_allclose(norm, np.linalg.norm(drift), rtol=1e-12)
        extra = rng.uniform(0.0, 1e-6)      # rad^2 per axis
        widened = covariance + extra * np.eye(2)
        statistic, norm = drift_statistic(sums, q, extra)
        np.testing.assert_allclose(statistic, drift @ np.linalg.solve(widened, drift), rtol=1e-9)
        np.testing.assert_allclose(norm, np.linalg.norm(drift), rtol=1e-12)


@pytest.mark.parametrize("missing", [None, "gyro", "accel", "both"])
def test_imu_sample_and_pose_is_the_sample_then_the_pose(missing):
    """fusion.imu_sample_and_pose against preintegration.imu_sample (a missing reading as NaN)
    followed by fusion.current_pose, on two copies of one interval."""
    rng = np.random.default_rng(5)
    a, b = Preintegration(9.81, 4.0, 0.1), Preintegration(9.81, 4.0, 0.1)
    a.start(rot.normalized(tuple(rng.normal(size=4))), rng.normal(0, 0.01, 3), rng.normal(0, 0.05, 3))
    a.remember(rng.normal(0, 0.3, 3), np.array([0.1, -0.2, 9.8]))
    b.record[:] = a.record
    position, velocity, lever = rng.normal(size=3), rng.normal(0, 0.1, 3), np.array([0.01, -0.02, 0.03])
    for _ in range(4):
        gyro, accel = rng.normal(0, 0.3, 3), np.array([0.1, -0.2, 9.8]) + rng.normal(0, 0.5, 3)
        have_gyro, have_accel = missing not in ("gyro", "both"), missing not in ("accel", "both")
        gyro, accel = gyro if have_gyro else MISSING, accel if have_accel else MISSING
        expected = imu_sample(a.record, gyro, accel, 0.001)
        expected_pose = current_pose(a.record, position, velocity, lever)
        status, interval, quaternion, *angles, position_now, velocity_now = imu_sample_and_pose(
            b.record, gyro, accel, 0.001, position, velocity, lever)
        assert (status, *quaternion, *angles) == expected
        assert interval == a.dt
        np.testing.assert_allclose((position_now, velocity_now), expected_pose, rtol=1e-12, atol=1e-14)
    assert a.record.tobytes() == b.record.tobytes()


def test_the_feet_roll_on_the_terrain_plane_s_normal_in_the_body_frame():
    slope = math.radians(10.0)
    terrain = np.array([math.tan(slope), 0.0, 0.1])            # rising 10 deg along x
    level = (0.0, 0.0, 0.0, 1.0)
    np.testing.assert_allclose(ground_normal_in_body(terrain, level), (-math.sin(slope), 0.0, math.cos(slope)),
                               atol=1e-12)
    along_the_slope = (0.0, math.sin(-slope / 2), 0.0, math.cos(-slope / 2))   # body pitched nose-up by 10 deg
    np.testing.assert_allclose(ground_normal_in_body(terrain, along_the_slope), (0.0, 0.0, 1.0), atol=1e-12)
    np.testing.assert_allclose(ground_normal_in_body(None, along_the_slope), rot.up_in_body(along_the_slope),
                               atol=1e-15)
