"""Sensor presets: names, data-sheet numbers, valid configs, clear errors, shipped as package data."""

import fnmatch
import math
import tomllib
from pathlib import Path

import pytest

from testbed.runtime import config
from testbed.model.errors import ConfigError
from testbed.runtime.presets import preset_names, preset_overrides

G0 = 9.80665
DEG = math.pi / 180
ROOT = Path(__file__).resolve().parents[2]


def load(name: str) -> config.Config:
    return config.load(None, preset_overrides(name))


def test_the_three_grades_are_listed_default_first():
    names = preset_names()
    assert names[0] == "default"
    assert {"default", "consumer", "tactical"} <= set(names)


def test_default_preset_changes_nothing():
    assert preset_overrides("default") == {}
    assert load("default") == config.load()


@pytest.mark.parametrize("name", ["consumer", "tactical"])
def test_presets_change_only_sensor_models_and_estimator_beliefs(name):
    overrides = preset_overrides(name)
    assert set(overrides) <= {"sensors", "estimators"}
    cfg, base = load(name), config.load()
    assert cfg.run == base.run and cfg.robot == base.robot
    assert cfg.sensors.imu.accel != base.sensors.imu.accel and cfg.sensors.imu.gyro != base.sensors.imu.gyro


def test_consumer_preset_holds_the_mpu6050_data_sheet_numbers():
    imu = load("consumer").sensors.imu
    assert imu.accel.noise_density == pytest.approx(400e-6 * G0, rel=1e-3)     # 400 ug/sqrt(Hz)
    assert imu.gyro.noise_density == pytest.approx(0.005 * DEG, rel=1e-3)      # 0.005 deg/s/sqrt(Hz)
    assert imu.gyro.turn_on_bias == pytest.approx(20 * DEG, rel=1e-3)          # +-20 deg/s ZRO
    assert imu.gyro.scale_factor == 0.03 and imu.gyro.misalignment == 0.02     # +-3 %, +-2 %
    assert imu.accel.bits == imu.gyro.bits == 16


def test_tactical_preset_holds_the_adis16470_data_sheet_numbers():
    imu = load("tactical").sensors.imu
    assert imu.gyro.noise_density == pytest.approx(0.008 * DEG, rel=1e-3)      # 0.008 deg/s/sqrt(Hz)
    assert imu.gyro.bias_instability == pytest.approx(8 * DEG / 3600, rel=1e-2)  # 8 deg/h
    assert imu.accel.bias_instability == pytest.approx(13e-6 * G0, rel=1e-2)    # 13 ug
    assert imu.accel.range == pytest.approx(40 * G0, rel=1e-3)                  # +-40 g


def test_grades_are_ordered_by_accelerometer_noise_and_gyro_offset():
    imus = [load(name).sensors.imu for name in ("consumer", "default", "tactical")]
    noise = [imu.accel.noise_density for imu in imus]
    offset = [imu.gyro.turn_on_bias for imu in imus]
    assert noise == sorted(noise, reverse=True) and offset == sorted(offset, reverse=True)


def test_the_ekf_beliefs_follow_the_part():
    for name in ("consumer", "tactical"):
        cfg = load(name)
        assert cfg.estimators.ekf.accel_noise_density == pytest.approx(cfg.sensors.imu.accel.noise_density, rel=0.02)
        assert cfg.estimators.ekf.gyro_bias_initial_std >= cfg.sensors.imu.gyro.turn_on_bias


def test_unknown_preset_is_one_clear_line():
    with pytest.raises(ConfigError) as error:
        preset_overrides("military")
    message = str(error.value)
    assert "military" in message and "consumer" in message and "\n" not in message


def test_overrides_are_a_fresh_dict_each_time():
    preset_overrides("consumer")["sensors"]["imu"]["accel"]["bits"] = 4
    assert preset_overrides("consumer")["sensors"]["imu"]["accel"]["bits"] == 16


def test_every_preset_file_is_shipped_as_package_data():
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["testbed"]
    for name in preset_names():
        assert any(fnmatch.fnmatch(f"presets/{name}.toml", glob) for glob in globs), name
