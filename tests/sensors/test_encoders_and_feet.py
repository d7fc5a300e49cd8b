"""Joint encoders (quantization, wrap, noise) and foot sensors (noise, saturation, hysteresis)."""

import math

import numpy as np
import pytest

from sensors.samples import EncoderSample, FootSample
from tests.sensors.helpers import of_type, run, sensors_config, steps, truth


def encoder_readings(config, angles):
    """One encoder sample per angle: all 18 joints at that angle."""
    states = [truth(k / config.encoder.rate, joint_positions=np.full(18, a)) for k, a in enumerate(angles)]
    return np.array([s.positions for s in of_type(run(config, states), EncoderSample)])


@pytest.mark.parametrize("bits", [12, 10])
def test_encoder_quantization_step_is_two_pi_over_two_to_the_bits(bits):
    config = sensors_config(encoder={"bits": bits, "noise": 0.0})
    angles = np.linspace(-1.0, 1.0, 3001)
    readings = encoder_readings(config, angles)[:, 0]
    steps_seen = np.diff(readings)
    assert np.min(steps_seen[steps_seen > 0]) == pytest.approx(2 * math.pi / 2**bits, rel=1e-9)
    assert np.all(np.isin(np.round(steps_seen / config.encoder.lsb), [0, 1]))
    assert np.max(np.abs(readings - angles)) <= config.encoder.lsb / 2 + 1e-12


def test_encoder_wraps_to_minus_pi_pi_and_noise_has_its_configured_sigma():
    config = sensors_config(encoder={"noise": 0.01})
    readings = encoder_readings(config, [math.pi + 0.1] * 400)
    assert np.all((readings >= -math.pi) & (readings < math.pi))
    assert np.mean(readings) == pytest.approx(-math.pi + 0.1, abs=1e-3)
    assert np.std(readings) == pytest.approx(0.01, rel=0.05)


def test_encoder_rate_is_200_samples_per_second_by_default():
    samples = of_type(run(sensors_config(), steps(1.0)), EncoderSample)
    assert len(samples) == 201 and samples[-1].t == 1.0


def test_foot_contact_flag_has_threshold_and_hysteresis():
    config = sensors_config(foot={"noise": 0.0})
    force_profile = [0.0, 0.8, 1.2, 0.8, 0.6, 0.4, 0.8, 1.1]     # N; on at 1.0, off at 0.5
    states = [truth(k / config.foot.rate, foot_forces=np.full(6, f)) for k, f in enumerate(force_profile)]
    samples = of_type(run(config, states), FootSample)
    assert [bool(s.contact[0]) for s in samples] == [False, False, True, True, True, False, False, True]
    np.testing.assert_allclose(samples[2].normal_forces, 1.2)


def test_foot_force_noise_and_saturation():
    config = sensors_config()
    samples = of_type(run(config, steps(2.0, lambda t: truth(t, foot_forces=[5.0, 5.0, 5.0, 5.0, 5.0, 80.0]))), FootSample)
    forces = np.array([s.normal_forces for s in samples])
    assert np.std(forces[:, :5]) == pytest.approx(config.foot.noise, rel=0.1)
    np.testing.assert_allclose(forces[:, 5], config.foot.full_scale)
    assert all(s.contact.all() for s in samples)


def test_compiled_digitizing_gives_the_numpy_expressions():
    """The encoders' wrap and the foot sensors' saturation and hysteresis are compiled; they give
    what the numpy expressions give (NaN included)."""
    from sensors.encoders import wrapped_counts
    from sensors.foot import contact_hysteresis, saturated
    rng = np.random.default_rng(8)
    for bits in (10, 12, 16):
        counts, lsb = 2**bits, 2 * math.pi / 2**bits
        raw = np.concatenate([rng.uniform(-20.0, 20.0, 5000), (np.arange(-4000, 4000) + 0.5) * lsb,
                              [0.0, -0.0, math.pi, -math.pi, np.nan]])
        half = counts // 2
        expected = ((np.rint(raw / lsb) + half) % counts - half) * lsb
        np.testing.assert_allclose(wrapped_counts(raw, lsb, counts), expected, rtol=1e-12, atol=1e-15)
    forces = np.concatenate([rng.normal(0.0, 300.0, 5000), [0.0, -0.0, 200.0, -200.0, np.nan, np.inf, -np.inf]])
    expected = np.minimum(np.maximum(forces, -200.0), 200.0)
    np.testing.assert_allclose(saturated(forces, 200.0), expected, rtol=1e-12, atol=1e-15)
    previous = rng.random(len(forces)) < 0.5
    np.testing.assert_array_equal(contact_hysteresis(forces, previous, 1.0, 0.5),
                                  (forces > 1.0) | (previous & (forces >= 0.5)))


def test_fault_free_encoder_and_foot_samples_in_one_call_equal_the_measure_path():
    """The one-call readings of a noisy sensor without faults against `measure` (corrupt, faults,
    digitize) on the same noise stream: angles past the wrap, forces past full scale, through the
    contact hysteresis."""
    from sensors.encoders import Encoders
    from sensors.foot import FootSensors
    config = sensors_config()
    rng = np.random.default_rng(3)
    pairs = [(Encoders(config.encoder, 4, ()), Encoders(config.encoder, 4, ())),
             (FootSensors(config.foot, 4, ()), FootSensors(config.foot, 4, ()))]
    for fast, slow in pairs:
        slow._plain = False
        assert fast._plain
        for k in range(3000):
            state = truth(k * 1e-3, joint_positions=rng.uniform(-4.0, 4.0, 18),
                          foot_forces=rng.choice([0.0, 0.7, 1.2, 49.99, 60.0], 6) + rng.normal(0.0, 0.3, 6))
            for ours, theirs in zip(fast.samples_at(state, k * 1e-3), slow.samples_at(state, k * 1e-3), strict=True):
                for name, value in vars(ours).items():
                    np.testing.assert_allclose(np.asarray(value), np.asarray(vars(theirs)[name]), rtol=1e-12, atol=1e-15)
