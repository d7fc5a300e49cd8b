"""Fault specs: the grammar, its errors, and each fault kind showing where and when requested and
nowhere else (a faulty run against a clean run with the same seed)."""

import math

import numpy as np
import pytest

from sensors.faults import parse_fault
from sensors.samples import FootSample, ImuSample
from testbed.model.errors import ConfigError
from tests.sensors.helpers import flatten, of_type, run, sensors_config, steps, truth

SECONDS = 1.0


def moving(t):
    """A truth whose every sensed quantity changes with time, so a stuck value shows."""
    phase = 2 * math.pi * t + np.arange(18)
    return truth(t, angular_velocity=(0.3 * math.sin(t), 0.2, -0.1), linear_acceleration=(0.5 * math.cos(3 * t), 0.0, 0.1),
                 joint_positions=0.5 * np.sin(phase), foot_forces=5.0 + 2.0 * np.sin(phase[:6]))


def clean_and_faulty(*specs, **sections):
    clean = flatten(run(sensors_config(**sections), steps(SECONDS, moving)))
    faulty = flatten(run(sensors_config(faults=list(specs), **sections), steps(SECONDS, moving)))
    return clean, faulty


def differences(clean, faulty):
    """{(stream, member, t): channels that differ (NaN counts as different)}; None: sample missing."""
    found = {}
    for key, values in clean.items():
        if key not in faulty:
            found[key] = None
            continue
        changed = np.flatnonzero(~np.isclose(values, faulty[key], rtol=0, atol=0))
        if len(changed):
            found[key] = set(changed.tolist())
    return found


def window(clean, stream, start, end, member=0):
    return sorted(t for (s, m, t) in clean if s == stream and m == member and start - 1e-9 <= t < end - 1e-9)


def test_fault_spec_grammar_parses_sensor_channel_kind_time_duration_and_value():
    fault = parse_fault("imu.gyro.z.bias_step@4s+250ms:0.02")
    assert (fault.sensor, fault.member, fault.channels, fault.kind) == ("imu", None, (5,), "bias_step")
    assert (fault.start, fault.end, fault.value) == (4.0, 4.25, 0.02)
    assert parse_fault("imu.accel.spike@5s").channels == (0, 1, 2)
    assert parse_fault("imu.dropout@1.5s").channels is None and parse_fault("imu.dropout@1.5s").end == math.inf
    assert parse_fault("encoder.leg2.dropout@3s+1s").channels == (3, 4, 5)
    assert parse_fault("encoder.leg6.tibia.stuck@0s").channels == (17,)
    assert parse_fault("foot.leg3.stuck@2s+1s:0").channels == (2,)
    assert (parse_fault("accel_array.3.y.spike@.5s").member, parse_fault("accel_array.3.y.spike@.5s").channels) == (3, (1,))


@pytest.mark.parametrize("spec, reason", [
    ("imu.accel.explode@1s", "unknown kind"),
    ("imu.accel.spike", "no '@START'"),
    ("imu.accel.spike@5", "unit s or ms"),
    ("imu.accel.spike@-1s", "unit s or ms"),
    ("imu.accel.spike@1s+1s", "takes no +DURATION"),
    ("imu.gyro.bias_step@1s", "needs its size"),
    ("imu.gyro.bias_step@1s:abc", "not a number"),
    ("imu.gyro.bias_step@1s:nan", "must be finite"),
    ("encoder.dropout@1s:3", "takes no :VALUE"),
    ("encoder.dropout@1s+0s", "duration must be positive"),
    ("foot.leg7.stuck@1s", "unknown leg"),
    ("encoder.leg1.knee.stuck@1s", "encoder channel"),
    ("imu.accel.w.spike@1s", "unknown axis"),
    ("imu.magnetometer.spike@1s", "imu channel"),
    ("lidar.dropout@1s", "unknown sensor"),
    ("accel_array.first.dropout@1s", "member index"),
    ("dropout@1s", "no sensor"),
])
def test_bad_fault_spec_raises_one_clear_config_error(spec, reason):
    with pytest.raises(ConfigError) as error:
        parse_fault(spec)
    message = str(error.value)
    assert reason in message and spec in message and "\n" not in message


def test_bad_fault_in_the_config_is_a_config_error():
    with pytest.raises(ConfigError, match="bad fault 'imu.spike'"):
        sensors_config(faults=["imu.spike"])
    with pytest.raises(ConfigError, match="accel_array has 0 member"):
        sensors_config(faults=["accel_array.0.dropout@1s"])


def test_fault_spike_hits_one_sample_at_the_requested_time_at_full_scale():
    clean, faulty = clean_and_faulty("imu.accel.spike@0.5s")
    assert differences(clean, faulty) == {("imu", 0, 0.5): {0, 1, 2}}
    accel = sensors_config().imu.accel
    np.testing.assert_allclose(faulty[("imu", 0, 0.5)][:3], accel.range - accel.lsb)


def test_fault_spike_with_a_value_on_one_array_member_axis():
    clean, faulty = clean_and_faulty("accel_array.2.x.spike@0.25s:5", accel_array={"layout": "quad"})
    assert differences(clean, faulty) == {("accel_array", 2, 0.25): {0}}
    key = ("accel_array", 2, 0.25)
    assert faulty[key][0] - clean[key][0] == pytest.approx(5.0, abs=sensors_config().imu.accel.lsb)


def test_fault_bias_step_shifts_one_gyro_axis_for_its_duration():
    clean, faulty = clean_and_faulty("imu.gyro.z.bias_step@0.2s+0.3s:0.02")
    times = window(clean, "imu", 0.2, 0.5)
    assert len(times) == 300
    assert differences(clean, faulty) == {("imu", 0, t): {5} for t in times}
    shifts = [faulty[("imu", 0, t)][5] - clean[("imu", 0, t)][5] for t in times]
    np.testing.assert_allclose(shifts, 0.02, atol=sensors_config().imu.gyro.lsb)


def test_fault_dropout_of_a_whole_sensor_removes_its_samples_in_the_window():
    clean, faulty = clean_and_faulty("encoder.dropout@0.3s+0.1s")
    times = window(clean, "encoder", 0.3, 0.4)
    assert len(times) == 20
    assert differences(clean, faulty) == {("encoder", 0, t): None for t in times}


def test_fault_dropout_of_one_leg_blanks_its_encoder_channels():
    clean, faulty = clean_and_faulty("encoder.leg2.dropout@0.3s+0.1s")
    times = window(clean, "encoder", 0.3, 0.4)
    assert differences(clean, faulty) == {("encoder", 0, t): {3, 4, 5} for t in times}
    assert all(np.isnan(faulty[("encoder", 0, t)][3:6]).all() for t in times)


def test_fault_dropout_of_the_imu_removes_imu_samples_only():
    clean, faulty = clean_and_faulty("imu.dropout@100ms+50ms")
    times = window(clean, "imu", 0.1, 0.15)
    assert len(times) == 50
    assert differences(clean, faulty) == {("imu", 0, t): None for t in times}


def test_fault_stuck_foot_holds_its_last_reading_then_recovers():
    clean, faulty = clean_and_faulty("foot.leg3.stuck@0.2s+0.1s")
    times = window(clean, "foot", 0.2, 0.3)
    before = max(t for (s, _, t) in clean if s == "foot" and t < 0.2)
    assert differences(clean, faulty) == {("foot", 0, t): {2} for t in times}
    assert all(faulty[("foot", 0, t)][2] == clean[("foot", 0, before)][2] for t in times)


def test_fault_stuck_at_a_value_until_the_end_clears_the_contact_flags():
    config = sensors_config(faults=["foot.stuck@0.5s:0"])
    samples = of_type(run(config, steps(SECONDS, moving)), FootSample)
    late = [s for s in samples if s.t >= 0.5]
    assert late and all((s.normal_forces == 0).all() and not s.contact.any() for s in late)
    assert all(s.contact.all() for s in samples if s.t < 0.5)


def test_fault_faults_on_accel_and_gyro_combine_and_stay_in_their_channels():
    clean, faulty = clean_and_faulty("imu.accel.y.dropout@0.6s+2ms", "imu.gyro.x.bias_step@0.7s+3ms:-0.05")
    expected = {("imu", 0, 0.6): {1}, ("imu", 0, 0.601): {1}}
    expected.update({("imu", 0, t): {3} for t in (0.7, 0.701, 0.702)})
    assert differences(clean, faulty) == expected


def test_fault_stuck_gyro_axis_holds_the_reading_before_the_window():
    clean, faulty = clean_and_faulty("imu.gyro.x.stuck@0.7s+3ms")
    held = clean[("imu", 0, 0.699)][3]
    assert [faulty[("imu", 0, t)][3] for t in (0.7, 0.701, 0.702)] == [held] * 3
    changed = differences(clean, faulty)
    assert set(changed) <= {("imu", 0, t) for t in (0.7, 0.701, 0.702)}
    assert all(channels == {3} for channels in changed.values())
