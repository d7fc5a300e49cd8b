"""IMU accelerometer and gyro: specific force with gravity and lever arm, the sensor's pose on the
body, systematic errors, saturation and quantization, the accelerometer array."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors.config import QUAD_POSITIONS
from sensors.faults import parse_fault
from sensors.imu import Imu
from sensors.motion import MotionCache
from sensors.samples import AccelSample, ImuSample
from tests.sensors.helpers import (GRAVITY, ideal_imu, of_type, pitched, run, sensors_config, steps, truth)

G_UP = np.array([0.0, 0.0, GRAVITY])


def mean_accel(config, make, seconds=1.0):
    samples = of_type(run(config, steps(seconds, make)), ImuSample)
    return np.mean([s.accel for s in samples], axis=0), len(samples)


@pytest.mark.parametrize("slope_deg", [0.0, 10.0])
def test_still_accelerometer_reads_gravity_within_three_sigma(slope_deg):
    config = sensors_config(imu=ideal_imu())
    rotation = pitched(slope_deg)
    mean, n = mean_accel(config, lambda t: truth(t, rotation))
    sigma_of_mean = config.imu.accel.noise_density * math.sqrt(config.imu.rate) / math.sqrt(n)
    np.testing.assert_array_less(np.abs(mean - rotation.T @ G_UP), 3 * sigma_of_mean)


def test_still_accelerometer_on_the_10_degree_slope_tilts_by_10_degrees():
    config = sensors_config(imu=ideal_imu())
    level, n = mean_accel(config, lambda t: truth(t))
    tilted, _ = mean_accel(config, lambda t: truth(t, pitched(10.0)))
    angle = math.degrees(math.acos(level @ tilted / np.linalg.norm(level) / np.linalg.norm(tilted)))
    sigma_deg = math.degrees(config.imu.accel.noise_density * math.sqrt(config.imu.rate / n) / GRAVITY)
    assert angle == pytest.approx(10.0, abs=3 * math.sqrt(2) * sigma_deg)


def test_still_accelerometer_applies_its_turn_on_bias_scale_factor_and_misalignment():
    config = sensors_config(imu={"accel": {"bias_instability": 0.0}})
    imu = Imu(config.imu, 3, (), MotionCache(GRAVITY))
    rotation = pitched(10.0)
    _, accel, _ = imu.record(truth(0.0, rotation), 1000)
    triad = imu.channels.triads[0]
    expected = triad.matrix @ (rotation.T @ G_UP) + triad.turn_on_bias
    sigma_of_mean = config.imu.accel.noise_density * math.sqrt(config.imu.rate / 1000)
    np.testing.assert_array_less(np.abs(accel.mean(axis=0) - expected), 3 * sigma_of_mean)
    assert np.linalg.norm(triad.turn_on_bias) > 0.01 and not np.allclose(triad.matrix, np.eye(3))


def spinning(omega_world, position, seconds=1.0):
    """An ideal IMU at `position` on a body spinning at a constant omega (world) about its origin."""
    omega = np.asarray(omega_world)
    config = sensors_config(imu=ideal_imu(position=list(position)))

    def make(t):
        return truth(t, Rotation.from_rotvec(omega * t).as_matrix(), angular_velocity=omega)
    return config, of_type(run(config, steps(seconds, make)), ImuSample), make


def test_accelerometer_on_a_lever_arm_reads_the_centripetal_acceleration_within_1_percent():
    omega, r = np.array([0.4, -0.8, 2 * math.pi]), np.array([0.10, 0.05, 0.02])
    _, samples, make = spinning(omega, r)
    # Omega is constant and along its own rotation axis, so it is the same in the body frame.
    centripetal = np.cross(omega, np.cross(omega, r))
    measured = np.mean([s.accel - make(s.t).body_rotation.T @ G_UP for s in samples], axis=0)
    assert np.linalg.norm(measured - centripetal) < 0.01 * np.linalg.norm(centripetal)
    assert np.linalg.norm(centripetal) > 3.0


def test_gyro_reads_the_body_frame_angular_velocity():
    omega = np.array([0.4, -0.8, 2 * math.pi])
    config, samples, _ = spinning(omega, (0.0, 0.0, 0.0))
    gyro = np.mean([s.gyro for s in samples], axis=0)
    sigma_of_mean = config.imu.gyro.noise_density * math.sqrt(config.imu.rate / len(samples))
    np.testing.assert_array_less(np.abs(gyro - omega), 3 * sigma_of_mean + config.imu.gyro.lsb)


def test_lever_arm_accelerometer_adds_the_tangential_term_and_the_body_acceleration():
    rotation = Rotation.from_euler("xyz", [5, -20, 70], degrees=True).as_matrix()
    omega, alpha, accel = np.array([1.0, -2.0, 3.0]), np.array([-4.0, 6.0, 2.0]), np.array([0.5, -1.0, 2.0])
    r_body = np.array([0.08, -0.06, 0.03])
    config = sensors_config(imu=ideal_imu(noise=False, position=list(r_body)))
    state = truth(0.0, rotation, angular_velocity=omega, angular_acceleration=alpha, linear_acceleration=accel)
    sample = of_type(run(config, [state]), ImuSample)[0]
    r = rotation @ r_body
    point_acceleration = accel + np.cross(alpha, r) + np.cross(omega, np.cross(omega, r))
    expected = rotation.T @ (point_acceleration + G_UP)
    np.testing.assert_allclose(sample.accel, expected, atol=config.imu.accel.lsb)
    assert np.linalg.norm(expected - rotation.T @ (accel + G_UP)) > 0.5


def test_accelerometer_reads_in_the_sensor_frame_of_its_pose():
    rpy = [10.0, -30.0, 90.0]
    config = sensors_config(imu=ideal_imu(noise=False, rpy_deg=rpy, position=[0.0, 0.0, 0.0]))
    rotation = pitched(10.0)
    sample = of_type(run(config, [truth(0.0, rotation, angular_velocity=(0.0, 0.0, 1.0))]), ImuSample)[0]
    body_from_sensor = Rotation.from_euler("ZYX", rpy[::-1], degrees=True).as_matrix()
    np.testing.assert_allclose(sample.accel, body_from_sensor.T @ rotation.T @ G_UP, atol=config.imu.accel.lsb)
    np.testing.assert_allclose(sample.gyro, body_from_sensor.T @ rotation.T @ [0.0, 0.0, 1.0], atol=config.imu.gyro.lsb)
    np.testing.assert_allclose(config.imu.body_from_sensor, body_from_sensor)


def test_accel_and_gyro_saturate_at_their_range_as_16_bit_counts():
    config = sensors_config(imu=ideal_imu(noise=False))
    accel, gyro = config.imu.accel, config.imu.gyro
    hard = truth(0.0, linear_acceleration=(80.0, -80.0, 0.0), angular_velocity=(50.0, -50.0, 1.0))
    sample = of_type(run(config, [hard]), ImuSample)[0]
    np.testing.assert_allclose(sample.accel[:2], [accel.range - accel.lsb, -accel.range])
    np.testing.assert_allclose(sample.gyro[:2], [gyro.range - gyro.lsb, -gyro.range])
    assert sample.gyro[2] == pytest.approx(1.0, abs=gyro.lsb)


def test_accel_and_gyro_readings_are_whole_counts_of_their_quantization_step():
    config = sensors_config()
    samples = of_type(run(config, steps(0.2, lambda t: truth(t, pitched(3.0), angular_velocity=(0.1, 0.2, 0.3)))), ImuSample)
    for values, lsb in (([s.accel for s in samples], config.imu.accel.lsb), ([s.gyro for s in samples], config.imu.gyro.lsb)):
        counts = np.array(values) / lsb
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert config.imu.accel.lsb == pytest.approx(2 * 6 * 9.80665 / 2**16, rel=1e-3)


def test_accel_array_quad_members_read_their_own_lever_arms():
    omega = np.array([0.0, 0.0, 2 * math.pi])
    config = sensors_config(accel_array={"layout": "quad"}, imu=ideal_imu(noise=False))
    state = truth(0.0, angular_velocity=omega)
    samples = of_type(run(config, [state]), AccelSample)
    assert [s.index for s in samples] == [0, 1, 2, 3]
    np.testing.assert_allclose(config.accel_array.member_positions, QUAD_POSITIONS)
    for sample, r in zip(samples, QUAD_POSITIONS):
        expected = np.cross(omega, np.cross(omega, r)) + G_UP
        np.testing.assert_allclose(sample.accel, expected, atol=config.imu.accel.lsb)


def test_accel_array_custom_positions_and_member_fault_selection():
    config = sensors_config(accel_array={"layout": "custom", "positions": [[0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]},
                            faults=["accel_array.1.dropout@0s"])
    samples = of_type(run(config, steps(0.01)), AccelSample)
    assert {s.index for s in samples} == {0} and len(samples) == 11
    assert parse_fault("accel_array.1.dropout@0s").member == 1
