import pytest

from estimators.base import Estimator
from estimators.registry import ESTIMATORS, make_estimator
from testbed.runtime import config as testbed_config
from testbed.model.errors import ConfigError, UserError


def test_defaults_hold_every_estimator_table():
    estimators = testbed_config.load().estimators
    assert estimators.ekf.accel_noise_density == pytest.approx(1.7e-3)
    assert estimators.vqf.motion_bias_estimation is True
    assert "[estimators.ekf]" in testbed_config.load().to_toml()


def test_resolved_config_round_trips():
    config = testbed_config.load().replace(estimators={"ukf": {"alpha": 0.5}})
    assert testbed_config.from_dict(config.to_dict()) == config


@pytest.mark.parametrize("section, values, message", [
    ("ekf", {"gyro_noise_density": -1.0}, "estimators.ekf.gyro_noise_density must be a positive finite number"),
    ("ekf", {"accel_gate_probability": 1.0}, "estimators.ekf.accel_gate_probability must lie in [0.5, 1)"),
    ("ekf", {"spike_body_accel": 0.0}, "estimators.ekf.spike_body_accel must be a positive finite number"),
    ("terrain", {"slope_random_walk": 0.0}, "estimators.terrain.slope_random_walk must be a positive"),
    ("ukf", {"alpha": 2.0}, "estimators.ukf.alpha must lie in (0, 1]"),
    ("mahony", {"k_i": -0.1}, "estimators.mahony.k_i must be a finite number >= 0"),
])
def test_bad_values_are_rejected_with_their_key(section, values, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        testbed_config.load().replace(estimators={section: values})


def test_unknown_estimator_key_is_rejected():
    with pytest.raises(ConfigError, match="unknown config key 'estimators.ekf.gain'"):
        testbed_config.load().replace(estimators={"ekf": {"gain": 1.0}})


def test_registry_builds_every_estimator_by_name():
    config = testbed_config.load()
    assert ESTIMATORS.names() == ("complementary", "ekf", "madgwick", "mahony", "ukf", "vqf")
    for name in ESTIMATORS.names():
        estimator = make_estimator(name, config)
        assert isinstance(estimator, Estimator) and estimator.name == name


def test_unknown_estimator_is_a_user_error():
    with pytest.raises(UserError) as error:
        make_estimator("kalman", testbed_config.load())
    assert str(error.value) == ("unknown estimator 'kalman' "
                                "(choose from complementary, ekf, madgwick, mahony, ukf, vqf, or give MODULE:CLASS)")
