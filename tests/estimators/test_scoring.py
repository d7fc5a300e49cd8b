import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from estimators.base import Estimate
from estimators.gating import chi2_quantile
from estimators.scoring import (METRIC_KEYS, EstimateArrays, TerrainTruth, anees_bounds, estimate_arrays,
                                roll_pitch_yaw, score, support_plane_truth, truth_at)
from estimators.terrain import fit_plane, heading_terrain_angles, slopes_and_height

T = np.arange(3000) / 1000.0
ROLL = 0.1 * np.sin(2 * np.pi * T)
PITCH = -0.05 + 0.03 * np.cos(2 * np.pi * T)
YAW = 1.0 + 0.5 * T                         # yaw must not leak into roll and pitch
TRUTH = Rotation.from_euler("ZYX", np.column_stack([YAW, PITCH, ROLL])).as_matrix()


def arrays(roll, pitch, cov=None, terrain=None) -> EstimateArrays:
    terrain = terrain or (None, None, None)
    return EstimateArrays(T, roll, pitch, cov, *terrain)


def test_truth_angles_use_the_estimates_euler_convention():
    assert np.allclose(roll_pitch_yaw(TRUTH), np.column_stack([ROLL, PITCH, YAW]))


def test_a_constant_roll_offset():
    offset = math.radians(0.5)
    roll = ROLL + offset
    roll[:1000] += 1.0                      # the first second is not scored
    cov = np.tile(np.diag([offset**2, offset**2]), (len(T), 1, 1))
    metrics = score(arrays(roll, PITCH, cov), T, TRUTH)
    assert set(metrics) == set(METRIC_KEYS)
    assert metrics["roll_rmse_deg"] == pytest.approx(0.5)
    assert metrics["pitch_rmse_deg"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["tilt_error_max_deg"] == pytest.approx(0.5, rel=1e-3)    # a roll error tilts by as much
    assert metrics["anees_tilt"] == pytest.approx(1.0)                      # (0.5 / 0.5)^2 + 0
    assert metrics["slope_error_deg"] is None and metrics["height_est_rmse_m"] is None


def test_without_covariance_there_is_no_anees():
    assert score(arrays(ROLL, PITCH), T, TRUTH)["anees_tilt"] is None


def test_tilt_error_is_the_angle_between_gravity_directions():
    # Rolled 60 deg, a 1 deg pitch error still moves the gravity direction by 1 deg.
    roll = np.full_like(T, math.radians(60.0))
    truth = Rotation.from_euler("ZYX", np.column_stack([YAW, np.zeros_like(T), roll])).as_matrix()
    metrics = score(arrays(roll, np.full_like(T, math.radians(1.0))), T, truth)
    assert metrics["tilt_error_max_deg"] == pytest.approx(1.0, rel=1e-3)
    assert metrics["pitch_rmse_deg"] == pytest.approx(1.0)


def test_terrain_metrics():
    truth = TerrainTruth(T, np.zeros_like(T), np.full_like(T, math.radians(-10.0)), np.full_like(T, 0.1))
    slope_error = np.where(T < 2.0, math.radians(5.0), math.radians(0.4))    # settles by 2 s
    height = np.where(T < 1.0, np.nan, 0.1 + 0.003 * np.sign(np.sin(7 * T)))
    terrain = (np.zeros_like(T), math.radians(-10.0) + slope_error, height)
    metrics = score(arrays(ROLL, PITCH, terrain=terrain), T, TRUTH, truth)
    assert metrics["slope_error_deg"] == pytest.approx(0.4, rel=1e-6)
    assert metrics["height_est_rmse_m"] == pytest.approx(0.003, rel=1e-3)


def test_estimate_arrays_from_estimates():
    q = np.array([0.0, 0.0, 0.0, 1.0])
    estimates = [Estimate(0.0, q, 0.1, 0.2, 0.0, attitude_cov=np.eye(3)),
                 Estimate(0.001, q, 0.1, 0.2, 0.0, attitude_cov=np.eye(3), terrain_roll=0.0, terrain_pitch=0.1,
                          body_height=0.1)]
    result = estimate_arrays(estimates)
    assert result.tilt_cov.shape == (2, 2, 2)
    assert np.isnan(result.body_height[0]) and result.body_height[1] == 0.1
    assert estimate_arrays([Estimate(0.0, q, 0.1, 0.2, 0.0)]).tilt_cov is None


def test_anees_bounds_of_the_issue():
    low, high = anees_bounds(10)
    assert (round(low, 2), round(high, 2)) == (0.96, 3.42)


def test_nothing_to_score_is_an_error():
    with pytest.raises(ValueError, match="no estimate after the first 5.0 s"):
        score(arrays(ROLL, PITCH), T, TRUTH, skip=5.0)


def per_step_support_planes(feet_world, support, body_position, yaw, foot_radius) -> np.ndarray:
    """(roll, pitch, height) per step, one plane fit at a time with the estimators' functions."""
    out = np.full((len(yaw), 3), np.nan)
    for k in range(len(yaw)):
        fit = fit_plane(feet_world[k][support[k]] - body_position[k], 0.0)
        if fit is not None:
            (a, b, height), _ = slopes_and_height(fit, foot_radius)
            out[k] = *heading_terrain_angles(a, b, yaw[k])[:2], height
    return out


def test_support_plane_truth_equals_a_per_step_fit():
    random = np.random.default_rng(7)
    steps = 400
    rotations = Rotation.from_euler("ZYX", random.uniform(-0.3, 0.3, (steps, 3)) * [10, 1, 1]).as_matrix()
    body_position = random.normal(0.0, 1.0, (steps, 3))
    feet_world = body_position[:, None, :] + random.normal([0.0, 0.0, -0.1], 0.15, (steps, 6, 3))
    feet_world[:5, :, 1] = body_position[:5, None, 1] + 0.001 * np.arange(6)    # collinear: no plane
    contact = random.random((steps, 6)) < 0.6
    forces = random.uniform(0.0, 10.0, (steps, 6))
    yaw = Rotation.from_matrix(rotations).as_euler("ZYX")[:, 0]
    truth = support_plane_truth(np.arange(steps) * 1e-3, feet_world, contact, body_position, rotations, 0.02,
                                normal_forces=forces, min_force=2.0)
    expected = per_step_support_planes(feet_world, contact & (forces >= 2.0), body_position, yaw, 0.02)
    actual = np.column_stack([truth.terrain_roll, truth.terrain_pitch, truth.body_height])
    assert np.array_equal(np.isnan(actual), np.isnan(expected)) and np.isfinite(expected).any()
    assert np.isnan(expected[:5]).all() and np.isnan(expected).any(axis=1).sum() > 5
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("probability, dof", [(0.025, 2), (0.975, 2), (0.99, 3), (0.5, 20), (0.999, 1)])
def test_chi2_quantile_is_the_chi_square_ppf(probability, dof):
    assert chi2_quantile(probability, dof) == pytest.approx(chi2.ppf(probability, dof), rel=1e-12)


def test_euler_angles_of_any_rotation_match_scipys():
    rotations = Rotation.random(2000, random_state=np.random.default_rng(5))
    np.testing.assert_allclose(roll_pitch_yaw(rotations.as_matrix()), rotations.as_euler("ZYX")[:, ::-1],
                               rtol=0, atol=1e-9)


def test_truth_at_a_step_is_the_steps_own_and_slerp_between():
    rng = np.random.default_rng(8)
    times = np.concatenate([T[[10, 500]] + rng.uniform(-1e-10, 1e-10, 2),        # at a step, within rounding
                            T[[20, 1500]] + 0.0004, [-1.0, 9.0]])                     # between steps; outside
    rotations = truth_at(times, T, TRUTH)
    np.testing.assert_array_equal(rotations[:2], TRUTH[[10, 500]])
    expected = Slerp(T, Rotation.from_matrix(TRUTH))(T[[20, 1500]] + 0.0004).as_matrix()
    np.testing.assert_allclose(rotations[2:4], expected, rtol=0, atol=1e-12)
    assert not np.allclose(rotations[2], TRUTH[20]) and not np.allclose(rotations[2], TRUTH[21])
    np.testing.assert_allclose(rotations[4:], TRUTH[[0, -1]], rtol=0, atol=1e-12)


def test_estimate_arrays_stack_arrays_shared_between_estimates_as_their_values():
    """An estimator may give consecutive estimates one covariance object: each estimate still has its row."""
    random = np.random.default_rng(3)
    a, b = (random.normal(size=(3, 3)) for _ in range(2))
    q = np.array([0.0, 0.0, 0.0, 1.0])
    held = [a, a, a, b, b.copy(), a, np.eye(3)]
    estimates = [Estimate(0.001 * k, q, 0.1, 0.2, 0.0, attitude_cov=cov, position=random.normal(size=3))
                 for k, cov in enumerate(held)]
    result = estimate_arrays(estimates)
    np.testing.assert_array_equal(result.attitude_cov, np.array(held))
    np.testing.assert_array_equal(result.tilt_cov, np.array(held)[:, :2, :2])
    np.testing.assert_array_equal(result.position, np.array([e.position for e in estimates]))
    assert result.velocity is None and result.terrain_roll is None
    estimates[4] = Estimate(0.004, q, 0.1, 0.2, 0.0, position=np.zeros(3))
    assert estimate_arrays(estimates).attitude_cov is None
    assert len(estimate_arrays([]).t) == 0 and estimate_arrays([]).tilt_cov is None
