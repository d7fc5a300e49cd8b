import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators.base import run_estimator
from estimators.config import TerrainEstimatorConfig
from estimators.leg_odometry import StanceTracker
from estimators.registry import make_estimator
from estimators.scoring import TerrainTruth, estimate_arrays, score, support_plane_truth
from estimators.terrain import TerrainFilter, fit_plane, heading_terrain_angles, slopes_and_height
from testbed.model.kinematics import inverse_kinematics_all
from tests.estimators import synthetic

SLOPE = math.radians(10.0)
DOWNHILL_AZIMUTH = math.radians(30.0)       # the plane rises along this horizontal direction
ATTITUDE = (math.radians(4.0), math.radians(-3.0), math.radians(20.0))    # roll, pitch, yaw
HEIGHT = 0.10                               # m, body origin above the contact plane


def plane_normal() -> np.ndarray:
    """Unit normal (gravity-aligned axes) of a 10 deg plane rising along DOWNHILL_AZIMUTH."""
    return Rotation.from_euler("ZY", [DOWNHILL_AZIMUTH, -SLOPE]).apply([0.0, 0.0, 1.0])


def feet_on_plane(config, stance: np.ndarray, body_from_world: np.ndarray) -> np.ndarray:
    """Body-frame foot centres on the plane, near the nominal stance: each foot is moved along
    the vertical onto the plane that lies HEIGHT below the body origin."""
    normal = plane_normal()
    world = stance @ body_from_world            # rows: R p, the nominal feet in world axes
    offset = HEIGHT - config.robot.foot_radius  # foot centres lie one radius above the contact plane
    world[:, 2] = -(offset + normal[0] * world[:, 0] + normal[1] * world[:, 1]) / normal[2]
    return world @ body_from_world.T


def expected_terrain_angles(yaw: float) -> tuple[float, float]:
    normal = plane_normal()
    a, b = -normal[0] / normal[2], -normal[1] / normal[2]
    roll, pitch, _ = heading_terrain_angles(a, b, yaw)
    return roll, pitch


@pytest.fixture(scope="module")
def standing_on_slope(config, geometry, stance):
    world_from_body = synthetic.euler_rotation(*ATTITUDE)
    feet = feet_on_plane(config, stance, world_from_body.T)
    return feet, inverse_kinematics_all(geometry, feet)


@pytest.mark.parametrize("legs", [[0, 2, 4], [1, 3, 5], list(range(6))])
def test_plane_fit_recovers_the_plane_from_encoder_angles(config, geometry, standing_on_slope, legs):
    _, joints = standing_on_slope
    feet = StanceTracker(geometry).feet(joints)[legs]
    world_from_body = synthetic.euler_rotation(*ATTITUDE)
    fit = fit_plane(feet @ world_from_body.T, position_std=3e-4)
    (a, b, height), covariance = slopes_and_height(fit, config.robot.foot_radius)
    fitted_normal = np.array([-a, -b, 1.0]) / math.hypot(1.0, a, b)
    assert math.degrees(math.acos(min(1.0, fitted_normal @ plane_normal()))) < 1e-6
    assert height == pytest.approx(HEIGHT, abs=1e-9)
    assert np.all(np.linalg.eigvalsh(covariance) > 0)


def test_plane_fit_with_quantised_encoders(config, geometry, standing_on_slope):
    _, joints = standing_on_slope
    lsb = 2 * math.pi / 4096
    feet = StanceTracker(geometry).feet(np.rint(joints / lsb) * lsb)
    fit = fit_plane(feet @ synthetic.euler_rotation(*ATTITUDE).T, position_std=3e-4)
    (a, b, height), _ = slopes_and_height(fit, config.robot.foot_radius)
    fitted_normal = np.array([-a, -b, 1.0]) / math.hypot(1.0, a, b)
    assert math.degrees(math.acos(min(1.0, fitted_normal @ plane_normal()))) < 0.2
    assert height == pytest.approx(HEIGHT, abs=5e-4)


def test_no_plane_from_fewer_than_three_or_collinear_feet():
    assert fit_plane(np.array([[0.1, 0.1, -0.1], [-0.1, 0.1, -0.1]]), 1e-3) is None
    line = np.array([[0.1 * k, 0.05 * k, -0.09] for k in (-1, 0, 1, 2)])
    assert fit_plane(line, 1e-3) is None


def test_heading_terrain_angles_describe_a_body_lying_on_the_plane():
    rng = np.random.default_rng(3)
    for a, b, yaw in rng.uniform([-0.5, -0.5, -math.pi], [0.5, 0.5, math.pi], (20, 3)):
        roll, pitch, jacobian = heading_terrain_angles(a, b, yaw)
        body_up = synthetic.euler_rotation(roll, pitch, yaw) @ [0.0, 0.0, 1.0]
        assert np.allclose(body_up, np.array([-a, -b, 1.0]) / math.hypot(1.0, a, b), atol=1e-12)
        step = 1e-7
        numeric = np.column_stack([(np.array(heading_terrain_angles(a + da, b + db, yaw)[:2]) - [roll, pitch]) / step
                                   for da, db in ((step, 0.0), (0.0, step))])
        assert np.allclose(numeric, jacobian, atol=1e-5)
    # Uphill straight ahead is nose up: negative pitch, as a body lying on it.
    roll, pitch, _ = heading_terrain_angles(math.tan(SLOPE), 0.0, 0.0)
    assert (math.degrees(roll), math.degrees(pitch)) == pytest.approx((0.0, -10.0))


def test_terrain_filter_smooths_and_restarts_on_a_step():
    terrain = TerrainFilter(TerrainEstimatorConfig(slope_random_walk=0.02, height_random_walk=0.01,
                                                   change_gate_probability=0.9999))
    noise = np.diag([1e-6, 1e-6, 1e-8])
    rng = np.random.default_rng(0)
    for k in range(50):
        terrain.update(0.02 * k, np.array([0.1, 0.0, 0.10]) + rng.normal(0.0, np.sqrt(np.diag(noise))), noise)
    assert terrain.restarts == 0
    assert np.all(np.diag(terrain.P) < np.diag(noise))     # better than one fit
    assert np.all(np.abs(terrain.x - [0.1, 0.0, 0.10]) < 4 * np.sqrt(np.diag(terrain.P)))
    terrain.update(1.0, np.array([0.1, 0.0, 0.14]), noise)      # the support dropped 4 cm
    assert terrain.restarts == 1
    assert terrain.x[2] == pytest.approx(0.14)


def test_standing_robot_reports_the_support_plane(config, geometry, spec, standing_on_slope):
    feet, _ = standing_on_slope
    trajectory = synthetic.still_trajectory(*ATTITUDE, duration=1.5, stance=feet, geometry=geometry)
    estimates = run_estimator(make_estimator("ekf", config), synthetic.samples(trajectory, spec, 5))
    last = estimates[-1]
    roll, pitch = expected_terrain_angles(ATTITUDE[2])
    assert math.degrees(last.terrain_roll - roll) == pytest.approx(0.0, abs=0.2)
    assert math.degrees(last.terrain_pitch - pitch) == pytest.approx(0.0, abs=0.2)
    assert last.body_height == pytest.approx(HEIGHT, abs=1e-3)
    sigma = np.sqrt(np.diag(last.terrain_cov))
    assert np.all(sigma > 0) and sigma[2] < 3e-3
    truth = support_plane_truth(trajectory.t[-1:], trajectory.feet_world[-1:] + [0.0, 0.0, 1.0],
                                trajectory.contact[-1:], np.array([[0.0, 0.0, 1.0]]), trajectory.rotation[-1:],
                                config.robot.foot_radius)
    assert (truth.terrain_roll[0], truth.terrain_pitch[0], truth.body_height[0]) == pytest.approx((roll, pitch, HEIGHT))


def test_support_plane_truth_matches_the_ground_of_the_slope_walk(config, slope_walk):
    truth = support_plane_truth(slope_walk.t[::50], slope_walk.feet_world[::50], slope_walk.contact[::50],
                                slope_walk.position[::50], slope_walk.rotation[::50], config.robot.foot_radius)
    assert np.allclose(truth.terrain_roll, slope_walk.terrain_roll[::50], atol=1e-9)
    assert np.allclose(truth.terrain_pitch, slope_walk.terrain_pitch[::50], atol=1e-9)
    assert np.allclose(truth.body_height, slope_walk.body_height[::50], atol=1e-9)


def test_walking_on_the_slope(config, spec, slope_walk):
    estimates = run_estimator(make_estimator("ekf", config), synthetic.samples(slope_walk, spec, 6))
    truth = TerrainTruth(slope_walk.t, slope_walk.terrain_roll, slope_walk.terrain_pitch, slope_walk.body_height)
    metrics = score(estimate_arrays(estimates), slope_walk.t, slope_walk.rotation, truth)
    assert metrics["slope_error_deg"] < 1.0      # within 1 deg after 2 s
    assert metrics["height_est_rmse_m"] < 5e-3
    assert max(metrics["roll_rmse_deg"], metrics["pitch_rmse_deg"]) < 0.1
