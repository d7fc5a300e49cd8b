"""The Encoder's directly written wire format against protobuf's own SerializeToString, byte for
byte: every message type, with zeros of both signs, NaN, infinities, empty and absent fields."""

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from datasets import codec, schemas, wire
from estimators.base import Estimate
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample
from testbed.world.contact import FootContacts
from testbed.control.command import Command
from testbed.model.truth import Truth

SPECIAL = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e-310, 5e-324, 1.0, -2.5])


def floats(rng: np.random.Generator, shape) -> np.ndarray:
    """Random numbers with special values sprinkled in."""
    values = rng.normal(size=shape)
    pick = rng.random(shape) < 0.3
    values[pick] = rng.choice(SPECIAL, size=int(pick.sum()))
    return values


def scalar(rng: np.random.Generator) -> float:
    return float(rng.choice(SPECIAL)) if rng.random() < 0.5 else float(rng.normal())


def protobuf_bytes(message_class, values: dict) -> bytes:
    """The reference: a protobuf message filled field by field, as codec's Encoder used to."""
    message = message_class()
    for name, value in values.items():
        if value is None:
            continue
        field = getattr(message, name)
        if isinstance(value, np.ndarray) or isinstance(value, list):
            field[:] = np.asarray(value).ravel().tolist()
        else:
            setattr(message, name, value)
    return message.SerializeToString()


@pytest.mark.parametrize("seed", range(40))
def test_hexapod_messages_are_protobufs_own_bytes(seed):
    rng = np.random.default_rng(seed)
    encoder = codec.Encoder()
    t = scalar(rng)
    contact = rng.random(6) < 0.5
    imu = ImuSample(t, floats(rng, 3), floats(rng, 3))
    assert encoder.sample(imu)[1] == protobuf_bytes(schemas.ImuSampleMsg, vars(imu))
    accel = AccelSample(t, int(rng.integers(0, 300)), floats(rng, 3))
    assert encoder.sample(accel)[1] == protobuf_bytes(schemas.AccelSampleMsg, vars(accel))
    joints = EncoderSample(t, floats(rng, 18))
    assert encoder.sample(joints)[1] == protobuf_bytes(schemas.EncoderSampleMsg, vars(joints))
    foot = FootSample(t, floats(rng, 6), contact)
    assert encoder.sample(foot)[1] == protobuf_bytes(schemas.FootSampleMsg, vars(foot))

    absent = rng.random(7) < 0.5
    estimate = Estimate(t=t, quaternion=floats(rng, 4), roll=scalar(rng), pitch=scalar(rng), yaw=scalar(rng),
                        attitude_cov=None if absent[0] else floats(rng, (3, 3)),
                        gyro_bias=None if absent[1] else floats(rng, 3),
                        gyro_bias_cov=None if absent[2] else floats(rng, (3, 3)),
                        terrain_roll=None if absent[3] else scalar(rng),
                        terrain_pitch=None if absent[4] else scalar(rng),
                        body_height=None if absent[5] else scalar(rng),
                        terrain_cov=None if absent[6] else floats(rng, (3, 3)))
    assert encoder.estimate(estimate) == protobuf_bytes(schemas.EstimateMsg, vars(estimate))

    truth = Truth(t, floats(rng, 3), floats(rng, (3, 3)), floats(rng, 3), floats(rng, 3), floats(rng, 3),
                  floats(rng, 3), floats(rng, 18), floats(rng, 18), floats(rng, (6, 3)), floats(rng, (6, 3)),
                  floats(rng, 6), contact, floats(rng, 3))
    assert encoder.truth_state(truth) == protobuf_bytes(schemas.TruthStateMsg, truth._asdict())
    assert encoder.feet(truth) == protobuf_bytes(schemas.FeetTruthMsg, {
        "t": t, "foot_positions": truth.foot_positions, "foot_contact": contact})

    contacts = FootContacts(floats(rng, (6, 3)), floats(rng, 6), floats(rng, (6, 3)), floats(rng, (6, 3)), contact)
    assert encoder.contacts(t, contacts) == protobuf_bytes(schemas.ContactsMsg, {"t": t, **contacts._asdict()})

    polygon, com, margin = floats(rng, (int(rng.integers(0, 7)), 2)), truth.com_position[:2], scalar(rng)
    assert encoder.support(t, polygon, com, margin) == protobuf_bytes(schemas.SupportMsg, {
        "t": t, "polygon": polygon, "com_projection": com, "stability_margin": margin})

    command = Command(t, floats(rng, 6), ~contact, floats(rng, (6, 3)), floats(rng, 18), floats(rng, 3))
    assert encoder.command(command) == protobuf_bytes(schemas.CommandMsg, command._asdict())


def foxglove_pose(t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
    message = PoseInFrame(frame_id=codec.WORLD_FRAME)
    message.timestamp.seconds, message.timestamp.nanos = divmod(t_ns, codec.NS_PER_S)
    p, o = message.pose.position, message.pose.orientation
    p.x, p.y, p.z = position.tolist()
    o.x, o.y, o.z, o.w = quaternion.tolist()
    return message.SerializeToString()


def foxglove_transform(t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
    message = FrameTransform(parent_frame_id=codec.WORLD_FRAME, child_frame_id=codec.BODY_FRAME)
    message.timestamp.seconds, message.timestamp.nanos = divmod(t_ns, codec.NS_PER_S)
    p, o = message.translation, message.rotation
    p.x, p.y, p.z = position.tolist()
    o.x, o.y, o.z, o.w = quaternion.tolist()
    return message.SerializeToString()


@pytest.mark.parametrize("t_ns", [0, 1, 999_999_999, 1_000_000_000, 1_500_000_000, 61_000_000_123, 2**40])
def test_foxglove_poses_and_transforms_are_protobufs_own_bytes(t_ns):
    rng = np.random.default_rng(t_ns % 1000)
    encoder = codec.Encoder()
    for _ in range(20):
        position, quaternion = floats(rng, 3), floats(rng, 4)
        assert encoder.pose(t_ns, position, quaternion) == foxglove_pose(t_ns, position, quaternion)
        assert encoder.transform(t_ns, position, quaternion) == foxglove_transform(t_ns, position, quaternion)


def test_arrays_of_any_layout_are_written_row_major():
    matrix = np.arange(12.0).reshape(3, 4)
    for view in (matrix.T, matrix[:, 1:3], matrix[::-1], np.asfortranarray(matrix)):
        expected = protobuf_bytes(schemas.EncoderSampleMsg, {"positions": view})
        assert wire.doubles(wire.key(2, wire.LENGTH_DELIMITED), view) == expected


@pytest.mark.parametrize("value", [0, 1, 127, 128, 300, 16383, 16384, 2**31 - 1, 2**63])
def test_varints(value):
    from google.protobuf.internal.encoder import _VarintBytes
    assert wire.varint(value) == _VarintBytes(value)


def test_nanoseconds_of_many_times_are_those_of_each():
    rng = np.random.default_rng(2)
    times = np.concatenate([rng.uniform(0, 600, 2000), np.arange(0, 10, 0.001), (np.arange(100) + 0.5) / 1e9])
    assert codec.to_ns_many(times.tolist()) == [codec.to_ns(t) for t in times.tolist()]


def test_poses_and_transforms_in_batches_are_those_one_at_a_time():
    rng = np.random.default_rng(5)
    encoder = codec.Encoder()
    times = sorted(rng.integers(0, 10**11, 300).tolist())
    positions, quaternions = floats(rng, (300, 3)), floats(rng, (300, 4))
    assert encoder.poses(times, positions, quaternions) == [
        foxglove_pose(t, p, q) for t, p, q in zip(times, positions, quaternions)]
    assert encoder.transforms(times, positions, quaternions) == [
        foxglove_transform(t, p, q) for t, p, q in zip(times, positions, quaternions)]
    assert encoder.poses([], [], []) == encoder.transforms([], [], []) == []
