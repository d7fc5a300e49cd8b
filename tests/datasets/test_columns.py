"""The recorder hands its writer each flush period's ticks as columns (`codec.TickColumns`) and the
writer serialises them: the file holds every tick's messages, in tick order, as the one-message
`codec.Encoder` serialises them; columns give back every value, absent ones and arrays of
different shapes included; a sensor plugin's samples get their own topic."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from mcap.reader import make_reader

from datasets import codec, schemas
from datasets.reader import read_recording
from datasets.recorder import McapRecorder
from tests.datasets.conftest import record
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
from testbed.runtime.recording import Tick


def expected_messages(ticks: list[Tick], every: int, urdf: str) -> list[tuple[str, int, int, bytes]]:
    """(topic, log time, sequence, data) of every tick's messages, one message at a time: its
    samples, estimates, pose and feet, then every `every` ticks its transforms, state, contacts,
    support and command."""
    encoder, to_ns = codec.Encoder(), codec.to_ns
    encoder.describe_robot(urdf)
    messages, sequence = [], 0
    for index, tick in enumerate(ticks):
        truth = tick.truth
        t_ns = to_ns(truth.t)
        for sample in tick.samples:
            topic, data = encoder.sample(sample)
            messages.append((topic, to_ns(sample.t), sequence, data))
            sequence += 1
        messages += [(schemas.ESTIMATE.name, to_ns(e.t), 0, encoder.estimate(e)) for e in tick.estimates]
        messages += [(schemas.TRUTH_POSE.name, t_ns, 0, encoder.pose(t_ns, truth.body_position, tick.truth_quaternion)),
                     (schemas.TRUTH_FEET.name, t_ns, 0, encoder.feet(truth))]
        if index % every == 0:
            support = encoder.support(truth.t, tick.support_polygon, truth.com_position[:2], tick.stability_margin)
            messages += [
                (schemas.TF.name, t_ns, 0, encoder.transforms(t_ns, truth.body_position, tick.truth_quaternion,
                                                                  truth.joint_positions)),
                (schemas.TRUTH_STATE.name, t_ns, 0, encoder.truth_state(truth)),
                (schemas.TRUTH_CONTACTS.name, t_ns, 0, encoder.contacts(truth.t, tick.contacts)),
                (schemas.TRUTH_SUPPORT.name, t_ns, 0, support),
                (schemas.COMMAND.name, to_ns(tick.command.t), 0, encoder.command(tick.command))]
    return messages


def recorded_messages(path) -> list[tuple[str, int, int, bytes]]:
    with open(path, "rb") as stream:
        return [(channel.topic, message.log_time, message.sequence, message.data)
                for _, channel, message in make_reader(stream).iter_messages(log_time_order=False)
                if channel.topic not in (schemas.TERRAIN.name, schemas.ROBOT_DESCRIPTION.name)]


def test_the_file_holds_every_tick_s_messages_in_order_as_the_encoder_serialises_them(ekf_run):
    config, ticks, path = ekf_run
    every = int(read_recording(path).run_info()["truth_every"])
    assert every > 1
    recorded, expected = recorded_messages(path), expected_messages(ticks, every, read_recording(path).urdf())
    assert len(recorded) == len(expected)
    for index, (a, b) in enumerate(zip(recorded, expected)):
        assert a == b, (index, a[:3], b[:3])


@pytest.mark.parametrize("values", [
    [1.5, 2.5, float("nan")],
    [True, False],
    [3, 7],
    [np.arange(6.0).reshape(2, 3), np.ones((2, 3))],
    [np.zeros((3, 2)), np.ones((5, 2)), np.zeros((0, 2))],         # polygons of different sizes
    [None, np.eye(3), None],
    [None, 0.25, 0.5],
    [None, None],
    [np.zeros((2, 0)), np.zeros((2, 0))],
    [],
], ids=["floats", "bools", "ints", "matrices", "ragged", "some-arrays-absent", "some-scalars-absent", "all-absent",
        "empty-arrays", "no-rows"])
def test_a_column_gives_back_each_row_s_value_flat(values):
    rows = codec.column_rows(codec.column(values), len(values))
    assert len(rows) == len(values)
    for row, value in zip(rows, values):
        if value is None:
            assert row is None
        elif isinstance(value, np.ndarray):
            assert row == value.ravel().tolist()
        else:
            assert type(row) is type(value) and np.array_equal(row, value, equal_nan=True)


@dataclass(frozen=True)
class ThermoSample:
    t: float
    celsius: float
    board: np.ndarray       # (2,) degC of the two boards


def with_thermometer(ticks: list[Tick]) -> list[Tick]:
    """The ticks with a plugin sample type's sample beside the built-in samples, every tenth tick."""
    return [tick._replace(samples=[*tick.samples, ThermoSample(tick.truth.t, 20.0 + index, np.array([1.0, index]))])
            if index % 10 == 0 else tick for index, tick in enumerate(ticks)]


def test_a_plugin_sample_type_is_recorded_on_its_own_topic(tmp_path):
    config = synthetic_config("complementary")
    ticks = with_thermometer(list(generate_ticks(config, 1.2)))
    path = tmp_path / "run.mcap"
    record(path, config, ticks)
    topic = schemas.sample_topic(ThermoSample)
    assert topic.name == "/sensors/tests.datasets.test_columns.ThermoSample"
    recording = read_recording(path)
    assert recording.channel_metadata[topic.name] == {"sample_class": "tests.datasets.test_columns:ThermoSample"}
    written = [sample for tick in ticks for sample in tick.samples]
    read = recording.samples()
    assert [type(sample) for sample in read] == [type(sample) for sample in written]
    thermo = [(s.t, s.celsius, s.board.tolist()) for s in read if isinstance(s, ThermoSample)]
    assert thermo == [(s.t, s.celsius, s.board.tolist()) for s in written if isinstance(s, ThermoSample)]
    assert len(thermo) == (len(ticks) + 9) // 10
    assert recorded_messages(path) == expected_messages(ticks, int(recording.run_info()["truth_every"]),
                                                        recording.urdf())


class NotADataclass:
    def __init__(self, t: float):
        self.t = t


def test_a_tick_with_a_sample_that_cannot_be_recorded_is_refused_in_the_run_loop(tmp_path):
    config = synthetic_config("complementary")
    ticks = list(generate_ticks(config, 0.6))
    recorder = McapRecorder(tmp_path / "run.mcap")
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    refused = 3
    for index, tick in enumerate(ticks):
        if index == refused:
            with pytest.raises(TypeError, match="NotADataclass"):
                recorder.record(tick._replace(samples=[*tick.samples, NotADataclass(tick.truth.t)]))
        else:
            recorder.record(tick)
    recorder.finish({}, None)
    kept = ticks[:refused] + ticks[refused + 1:]
    assert recorded_messages(recorder.path) == expected_messages(kept, recorder._every, urdf)
