"""The suite's one interface: sample times decoupled from the physics step, time order,
sample-and-hold of truth, and determinism (same seed, same samples)."""

import numpy as np
import pytest

from sensors.imu import Imu
from sensors.motion import MotionCache
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample
from sensors.suite import SensorSuite
from testbed.runtime import config as testbed_config
from tests.sensors.helpers import GRAVITY, flatten, ideal_imu, of_type, run, sensors_config, steps, truth


def test_accel_gyro_at_400_hz_with_a_1_khz_physics_step_emit_400_samples_per_second():
    config = sensors_config(imu={"rate": 400.0})
    suite = SensorSuite.from_sections(config, GRAVITY, 0)
    previous = None
    imu_times = []
    for state in steps(2.0):
        batch = suite.update(state)
        assert [s.t for s in batch] == sorted(s.t for s in batch)
        assert all(previous is None or previous.t < s.t <= state.t for s in batch)
        imu_times += [s.t for s in of_type(batch, ImuSample)]
        previous = state
    second = [t for t in imu_times if 1.0 < t <= 2.0]
    assert len(second) == 400
    np.testing.assert_array_equal(second, np.arange(401, 801) / 400.0)


def test_accel_samples_between_physics_steps_read_the_latest_truth_before_them():
    config = sensors_config(imu=ideal_imu(noise=False, rate=400.0, position=[0.0, 0.0, 0.0]))
    # The truth's vertical acceleration encodes its own time: 1000 t m/s^2.
    samples = of_type(run(config, steps(0.02, lambda t: truth(t, linear_acceleration=(0.0, 0.0, 1000.0 * t)))), ImuSample)
    for sample in samples:
        truth_time = np.floor(sample.t * 1000.0 + 1e-6) / 1000.0
        assert sample.accel[2] == pytest.approx(GRAVITY + 1000.0 * truth_time, abs=config.imu.accel.lsb)
    assert [s.t for s in samples][:4] == [0.0, 0.0025, 0.005, 0.0075]


def test_update_returns_every_stream_in_time_order_with_its_own_timestamps():
    config = sensors_config(accel_array={"layout": "quad"})
    samples = run(config, steps(1.0, step=0.004))
    assert [s.t for s in samples] == sorted(s.t for s in samples)
    counts = {kind: len(of_type(samples, kind)) for kind in (ImuSample, AccelSample, EncoderSample, FootSample)}
    assert counts == {ImuSample: 1001, AccelSample: 4 * 1001, EncoderSample: 201, FootSample: 251}


def moving(t):
    return truth(t, angular_velocity=(0.1, 0.2, np.sin(t)), joint_positions=np.full(18, 0.3 * t),
                 foot_forces=np.full(6, 3.0 + t))


def assert_same(first, second):
    assert first.keys() == second.keys()
    for key in first:
        np.testing.assert_array_equal(first[key], second[key])


def test_same_seed_gives_identical_accel_gyro_encoder_and_foot_samples():
    config = sensors_config(accel_array={"layout": "quad"}, faults=["foot.leg1.stuck@0.1s+0.1s"])
    assert_same(flatten(run(config, steps(0.5, moving), seed=7)), flatten(run(config, steps(0.5, moving), seed=7)))


def test_different_seed_gives_different_accel_gyro_encoder_and_foot_samples():
    config = sensors_config(accel_array={"layout": "quad"})
    first, second = flatten(run(config, steps(0.2, moving), seed=7)), flatten(run(config, steps(0.2, moving), seed=8))
    for stream in ("imu", "accel_array", "encoder", "foot"):
        keys = [key for key in first if key[0] == stream]
        assert not all(np.array_equal(first[k], second[k]) for k in keys), stream


def test_adding_accel_array_members_leaves_the_other_sensor_streams_unchanged():
    alone = flatten(run(sensors_config(), steps(0.3, moving)))
    with_array = flatten(run(sensors_config(accel_array={"layout": "quad"}), steps(0.3, moving)))
    assert_same(alone, {key: value for key, value in with_array.items() if key[0] != "accel_array"})


def test_still_imu_record_is_the_vectorised_path_of_the_per_step_accel_gyro_samples():
    config = sensors_config()
    still = truth(0.0)
    _, accel, gyro = Imu(config.imu, 5, (), MotionCache(GRAVITY)).record(still, 3000)
    samples = of_type(run(config, [truth(k / 1000.0) for k in range(3000)], seed=5), ImuSample)
    np.testing.assert_allclose(accel, [s.accel for s in samples], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(gyro, [s.gyro for s in samples], rtol=1e-12, atol=1e-15)


def test_suite_from_the_run_config_uses_its_gravity_and_seed():
    config = testbed_config.load(overrides={"run": {"gravity": 9.0, "seed": 11},
                                            "sensors": {"imu": ideal_imu(noise=False, position=[0.0, 0.0, 0.0])}})
    sample = SensorSuite.from_config(config).update(truth(0.0))[0]
    assert sample.accel[2] == pytest.approx(9.0, abs=config.sensors.imu.accel.lsb)
