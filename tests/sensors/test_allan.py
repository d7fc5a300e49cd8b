"""Allan deviation: the tool on white noise, and the noise terms of the IMU model recovered from
simulated still records (IEEE Std 952 relations, sensors/allan.py)."""

import math

import numpy as np
import pytest
from scipy.signal import sosfreqz

from sensors.allan import FLICKER_FLOOR, NoiseTerms, allan_deviation, cluster_sizes, fit_noise_terms, model_deviation
from sensors.imu import Imu
from sensors.inertial_errors import FLICKER_BAND, flicker_filter
from sensors.motion import MotionCache
from tests.sensors.helpers import GRAVITY, IDEAL_AXES, ideal_imu, sensors_config, truth

HOUR = 3600.0


def still_record(config, hours, seed=0):
    imu = Imu(config.imu, seed, (), MotionCache(GRAVITY))
    _, accel, gyro = imu.record(truth(), int(hours * HOUR * config.imu.rate))
    return accel, gyro


def test_allan_deviation_of_white_noise_falls_as_sigma_over_sqrt_m():
    samples = np.random.default_rng(1).standard_normal((400_000, 2))
    tau, deviation = allan_deviation(samples, 100.0, np.array([1, 10, 100, 1000]))
    np.testing.assert_allclose(tau, [0.01, 0.1, 1.0, 10.0])
    np.testing.assert_allclose(deviation, 1 / np.sqrt([[1, 1], [10, 10], [100, 100], [1000, 1000]]), rtol=0.05)


def test_allan_flicker_filter_spectrum_is_the_flicker_law_inside_its_band():
    dt, bias_instability = 1e-3, 2.0
    frequency = np.logspace(-np.log10(FLICKER_BAND[1]) + 1, -np.log10(FLICKER_BAND[0]) - 1, 200) / (2 * np.pi)
    _, response = sosfreqz(flicker_filter(bias_instability, dt), worN=2 * np.pi * frequency * dt)
    density = dt * np.abs(response) ** 2
    np.testing.assert_allclose(density, bias_instability**2 / (2 * np.pi * frequency), rtol=0.01)


def test_allan_model_deviation_has_the_ieee_952_slopes():
    terms = NoiseTerms(noise_density=2.0, bias_instability=3.0, rate_random_walk=0.0)
    assert model_deviation(np.array([1.0]), NoiseTerms(2.0, 0.0, 0.0))[0] == pytest.approx(2.0)
    assert model_deviation(np.array([1e9]), terms)[0] == pytest.approx(FLICKER_FLOOR * 3.0, rel=1e-6)
    assert model_deviation(np.array([3.0]), NoiseTerms(0.0, 0.0, 5.0))[0] == pytest.approx(5.0)


def test_allan_recovers_noise_density_and_bias_instability_from_one_hour_still_imu():
    """One hour at 1 kHz, default BMI088 accelerometer; the gyro's bias instability raised from
    the default 2 deg/h to 0.03 deg/s (108 deg/h). The floor 0.664 B shows only where it exceeds
    the white noise N / sqrt(tau), after tau_c = (N / 0.664 B)^2: 7 s for the default accelerometer,
    but 1400 s for the default gyro, where one hour holds too few clusters to fix B within 10 %."""
    config = sensors_config(imu={"gyro": {"bias_instability": math.radians(0.03)}})
    accel, gyro = still_record(config, hours=1.0)
    sizes = cluster_sizes(len(accel), per_decade=5, max_fraction=0.01)     # tau up to 36 s
    tau, deviation = allan_deviation(np.hstack((accel, gyro)), config.imu.rate, sizes)
    for columns, axes in ((slice(0, 3), config.imu.accel), (slice(3, 6), config.imu.gyro)):
        terms = fit_noise_terms(tau, deviation[:, columns])
        assert terms.noise_density == pytest.approx(axes.noise_density, rel=0.1)
        assert terms.bias_instability == pytest.approx(axes.bias_instability, rel=0.1)


def test_allan_recovers_the_rate_random_walk():
    walk = 3e-3     # m/s^2/sqrt(s): meets the white noise at tau = sqrt(3) N / K = 1 s
    config = sensors_config(imu=ideal_imu(rate=100.0, accel=dict(IDEAL_AXES, rate_random_walk=walk)))
    accel, _ = still_record(config, hours=2.0)
    tau, deviation = allan_deviation(accel, config.imu.rate, cluster_sizes(len(accel), per_decade=5))
    terms = fit_noise_terms(tau, deviation)
    assert terms.rate_random_walk == pytest.approx(walk, rel=0.1)
    assert terms.noise_density == pytest.approx(config.imu.accel.noise_density, rel=0.1)
