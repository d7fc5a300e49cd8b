"""The compiled layout of a flush's records (datasets.batch_encode) is the Python encoder's, byte
for byte: the recorder's message tuples, each made a record as mcap writes it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from datasets import batch_encode
from datasets.mcap_batch import MESSAGE_FIELDS_SIZE, MESSAGE_HEADER
from datasets.recorder import McapRecorder, _Step
from sensors.samples import AccelSample
from tests.datasets.conftest import faulty_config
from tests.datasets.test_wire import SPECIAL, floats
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
from testbed.world.contact import FootContacts


def _recorder(tmp_path, config) -> McapRecorder:
    recorder = McapRecorder(tmp_path / "run.mcap")
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    return recorder


def _steps(recorder: McapRecorder, ticks) -> list[tuple]:
    """What `record` keeps of the ticks, without writing them."""
    recorder._next_flush_ns = 2**62
    for tick in ticks:
        recorder.record(tick)
    steps, recorder._pending = recorder._pending, []
    return steps


def _python_records(recorder: McapRecorder, steps, first_sequence: int) -> batch_encode.Batch:
    """The Python encoder's messages as `lay_out` gives them."""
    recorder._samples = first_sequence
    messages = recorder._messages([_Step._make(step) for step in steps])
    records = [MESSAGE_HEADER.pack(5, MESSAGE_FIELDS_SIZE + len(data), channel, sequence, log_time, log_time) + data
               for channel, log_time, data, sequence in messages]
    return batch_encode.Batch(np.frombuffer(b"".join(records), np.uint8),
                              np.cumsum([len(record) for record in records], dtype=np.int64),
                              np.array([message[0] for message in messages], np.int64),
                              np.array([message[1] for message in messages], np.int64))


def assert_same_records(recorder: McapRecorder, steps, first_sequence: int = 0) -> None:
    laid_out = batch_encode.lay_out(steps, recorder._channel_of, first_sequence)
    assert laid_out is not None, "the compiled path refused the batch"
    expected = _python_records(recorder, steps, first_sequence)
    assert len(laid_out.ends) == len(expected.ends)
    assert laid_out.channels.tolist() == expected.channels.tolist()
    assert laid_out.log_times.tolist() == expected.log_times.tolist()
    assert laid_out.ends.tolist() == expected.ends.tolist()
    assert laid_out.records.tobytes() == expected.records.tobytes()


@pytest.mark.parametrize("estimator", ["ekf", "complementary", "vqf", "no estimates"])
def test_a_run_with_faults_and_every_sample_type_is_laid_out_as_the_python_encoder_writes_it(tmp_path, estimator):
    """Faults put NaN into samples and clear contact flags; the accelerometer array adds its
    samples (an unsigned field); the complementary filter leaves covariances absent."""
    config = faulty_config("ekf" if estimator == "no estimates" else estimator)
    recorder = _recorder(tmp_path, config)
    ticks = generate_ticks(config, 1.3)
    if estimator == "no estimates":
        ticks = (tick._replace(estimates=[]) for tick in ticks)
    steps = _steps(recorder, ticks)
    assert {type(sample) for step in steps for sample in step[5]} >= {AccelSample}
    for first, last in ((0, len(steps)), (0, 1), (1, 2), (7, 512), (600, len(steps))):
        assert_same_records(recorder, steps[first:last], first_sequence=first * 3)
    recorder.finish({}, None)


def _odd(tick, rng: np.random.Generator):
    """The tick with special values: zeros of both signs, NaN, infinities in the pose, truth,
    contacts and command; a support polygon of 0 to 6 corners; absent and zero optional fields."""
    truth = tick.truth
    special = {name: floats(rng, value.shape) for name, value in truth._asdict().items()
               if isinstance(value, np.ndarray) and value.dtype == float}
    truth = truth._replace(t=truth.t, **special)
    corners = int(rng.integers(0, 7))
    contacts = FootContacts(*(floats(rng, value.shape) if value.dtype == float else rng.random(value.shape) < 0.5
                              for value in tick.contacts))
    command = tick.command._replace(**{name: floats(rng, value.shape) for name, value in tick.command._asdict().items()
                                       if isinstance(value, np.ndarray) and value.dtype == float})
    estimates = [dataclasses.replace(estimate, roll=float(rng.choice(SPECIAL)),
                                     terrain_roll=[None, 0.0, -0.0, float(rng.normal())][rng.integers(4)],
                                     attitude_cov=[None, np.zeros((0, 3)), estimate.attitude_cov][rng.integers(3)])
                 for estimate in tick.estimates]
    return tick._replace(truth=truth, truth_quaternion=floats(rng, 4), contacts=contacts,
                         support_polygon=floats(rng, (corners, 2)), stability_margin=float(rng.choice(SPECIAL)),
                         command=command, estimates=estimates)


@pytest.mark.parametrize("seed", range(4))
def test_special_values_and_polygons_of_every_size_are_laid_out_as_the_python_encoder_writes_them(tmp_path, seed):
    rng = np.random.default_rng(seed)
    config = synthetic_config("ekf")
    recorder = _recorder(tmp_path, config)
    steps = _steps(recorder, [_odd(tick, rng) for tick in generate_ticks(config, 0.2)])
    assert_same_records(recorder, steps)
    recorder.finish({}, None)


def test_an_empty_batch_has_no_records(tmp_path):
    recorder = _recorder(tmp_path, synthetic_config("ekf"))
    laid_out = batch_encode.lay_out([], recorder._channel_of, 0)
    assert len(laid_out.records) == len(laid_out.ends) == 0
    recorder.finish({}, None)


def test_values_the_compiled_path_does_not_take_go_to_the_python_encoder(tmp_path):
    """A boolean array index: the Python encoder writes it as 1; the compiled path refuses it,
    and the recording is the Python encoder's."""
    config = faulty_config("ekf")
    ticks = list(generate_ticks(config, 0.6))
    odd = [tick._replace(samples=[dataclasses.replace(sample, index=True) if isinstance(sample, AccelSample)
                                  else sample for sample in tick.samples]) for tick in ticks]
    recorder = _recorder(tmp_path, config)
    steps = _steps(recorder, odd)
    assert batch_encode.lay_out(steps, recorder._channel_of, 0) is None
    recorder._pending = steps
    recorder.finish({}, None)
    from datasets.reader import read_recording
    indexes = {sample.index for sample in read_recording(recorder.path).samples() if isinstance(sample, AccelSample)}
    assert indexes == {1}
