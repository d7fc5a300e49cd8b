"""The [sensors] config: defaults, round trip through TOML, and one clear error per bad value."""

import math
import tomllib

import pytest

from sensors.config import SensorsConfig
from testbed.runtime import config as testbed_config
from testbed.model.errors import ConfigError
from tests.sensors.helpers import sensors_config


def test_sensor_defaults_are_the_bmi088_numbers_in_si_units():
    imu = sensors_config().imu
    assert imu.accel.noise_density == pytest.approx(175e-6 * 9.80665, rel=1e-3)
    assert imu.gyro.noise_density == pytest.approx(math.radians(0.014), rel=1e-3)
    assert imu.gyro.bias_instability == pytest.approx(math.radians(2 / 3600), rel=1e-2)
    assert imu.accel.range == pytest.approx(6 * 9.80665, rel=1e-3) and imu.gyro.range == pytest.approx(math.radians(2000), rel=1e-3)
    assert imu.rate == 1000.0 and sensors_config().encoder.bits == 12 and sensors_config().encoder.rate == 200.0


def test_sensor_config_round_trips_through_toml_with_faults_and_custom_accel_positions():
    config = testbed_config.load(overrides={"sensors": {
        "faults": ["imu.accel.spike@5s", "encoder.leg2.dropout@3s+1s"],
        "accel_array": {"layout": "custom", "positions": [[0.1, 0.0, 0.0], [0.0, -0.1, 0.02]]}}})
    again = testbed_config.from_dict(tomllib.loads(config.to_toml()))
    assert again.sensors == config.sensors and isinstance(again.sensors, SensorsConfig)
    assert again.sensors.accel_array.member_positions.shape == (2, 3)
    assert [f.kind for f in again.sensors.parsed_faults] == ["spike", "dropout"]


@pytest.mark.parametrize("sensors, message", [
    ({"imu": {"rate": 0.0}}, "sensors.imu.rate must lie in (0, 10000] Hz"),
    ({"imu": {"rate": math.nan}}, "sensors.imu.rate"),
    ({"imu": {"accel": {"noise_density": math.nan}}}, "sensors.imu.accel.noise_density must be a finite number >= 0"),
    ({"imu": {"gyro": {"bias_instability": -1.0}}}, "sensors.imu.gyro.bias_instability"),
    ({"imu": {"gyro": {"scale_factor": 0.5}}}, "sensors.imu.gyro.scale_factor must lie in [0, 0.1]"),
    ({"imu": {"accel": {"bits": 2}}}, "sensors.imu.accel.bits must lie in [4, 32]"),
    ({"imu": {"accel": {"range": 0.0}}}, "sensors.imu.accel.range"),
    ({"imu": {"position": [0.0, 0.0]}}, "sensors.imu.position needs 3 numbers"),
    ({"imu": {"rpy_deg": [0.0, math.inf, 0.0]}}, "sensors.imu.rpy_deg must be finite"),
    ({"accel_array": {"layout": "hex"}}, "unknown sensors.accel_array.layout 'hex'"),
    ({"accel_array": {"layout": "custom"}}, "sensors.accel_array.positions needs 1 to 64"),
    ({"accel_array": {"positions": [[0.0, 0.0, 0.0]]}}, "only for layout 'custom'"),
    ({"accel_array": {"layout": "custom", "positions": [[0.0, 0.0]]}}, "positions[0] needs 3 numbers"),
    ({"encoder": {"bits": 40}}, "sensors.encoder.bits must lie in [4, 24]"),
    ({"encoder": {"noise": -0.1}}, "sensors.encoder.noise"),
    ({"foot": {"contact_off": 2.0}}, "contact_off < contact_on"),
    ({"foot": {"full_scale": -5.0}}, "sensors.foot.full_scale"),
    ({"faults": ["imu.accel.spike@soon"]}, "bad fault 'imu.accel.spike@soon'"),
    ({"imu": {"accel": {"noise": 1.0}}}, "unknown config key 'sensors.imu.accel.noise'"),
    ({"faults": "imu.accel.spike@1s"}, "config key 'sensors.faults' must be a list"),
])
def test_bad_sensor_config_raises_one_clear_config_error(sensors, message):
    with pytest.raises(ConfigError) as error:
        testbed_config.load(overrides={"sensors": sensors})
    assert message in str(error.value) and "\n" not in str(error.value)
