"""The config: defaults load, overrides merge, every bad value is named."""

import math

import pytest

from testbed.runtime import config
from testbed.model.errors import ConfigError


def test_defaults_load_and_round_trip_through_toml(tmp_path):
    cfg = config.load()
    assert cfg.run.time_step == 0.001 and cfg.run.terrain == "flat"
    saved = tmp_path / "resolved.toml"
    saved.write_text(cfg.to_toml())
    assert config.load(saved) == cfg


def test_user_file_overrides_a_subset(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[terrain]\nslope_deg = -7.5\n[run]\nterrain = "slope"\n')
    cfg = config.load(path)
    assert cfg.terrain.slope_deg == -7.5 and cfg.run.terrain == "slope"
    assert cfg.robot == config.load().robot


@pytest.mark.parametrize("overrides, message", [
    ({"run": {"terrain": "moon"}}, "unknown terrain 'moon'"),
    ({"run": {"contact": "glue"}}, "unknown contact model 'glue'"),
    ({"run": {"duration": 0.0}}, "run.duration"),
    ({"run": {"duration": -1.0}}, "run.duration"),
    ({"run": {"duration": math.nan}}, "run.duration"),
    ({"run": {"time_step": 0.1}}, "too coarse"),
    ({"run": {"seed": -1}}, "run.seed"),
    ({"run": {"colour": 1}}, "unknown config key 'run.colour'"),
    ({"robot": {"body_size": [0.2, 0.1]}}, "body_size"),
    ({"robot": {"femur_length": math.inf}}, "positive finite"),
    ({"robot": {"joint_lower_deg": [70.0, 0.0, 0.0]}}, "joint limits"),
    ({"terrain": {"slope_deg": 60.0}}, "slope_deg"),
    ({"contact": {"friction": -0.1}}, "friction"),
    ({"contact": {"stiffness": "hard"}}, "must be a number"),
    ({"posture": {"tilt_large_kp": -1.0}}, "posture gains"),
    ({"posture": {"tilt_large_error_deg": 15.0}}, "posture.tilt_large_error_deg"),
])
def test_bad_values_are_rejected_with_their_name(overrides, message):
    with pytest.raises(ConfigError, match=message):
        config.load(overrides=overrides)


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        config.load(tmp_path / "absent.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[run\nterrain = ")
    with pytest.raises(ConfigError, match="invalid TOML"):
        config.load(broken)
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="cannot read"):
        config.load(binary)
