"""Every message type encodes and decodes back to the same values: zeros of both signs, NaN,
infinities, empty and absent fields included, also when one encoder serialises message after
message of changing shape."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass

from datasets import codec
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


def same(a, b) -> None:
    """Equal bit for bit (NaN payloads and the sign of zero included), shapes and dtypes too."""
    if a is None or b is None:
        assert a is None and b is None
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def random_estimate(rng: np.random.Generator, t: float) -> Estimate:
    absent = rng.random(7) < 0.5
    return Estimate(t=t, quaternion=floats(rng, 4), roll=scalar(rng), pitch=scalar(rng), yaw=scalar(rng),
                    attitude_cov=None if absent[0] else floats(rng, (3, 3)),
                    gyro_bias=None if absent[1] else floats(rng, 3),
                    gyro_bias_cov=None if absent[2] else floats(rng, (3, 3)),
                    terrain_roll=None if absent[3] else scalar(rng),
                    terrain_pitch=None if absent[4] else scalar(rng),
                    body_height=None if absent[5] else scalar(rng),
                    terrain_cov=None if absent[6] else floats(rng, (3, 3)))


def test_every_message_type_comes_back_bit_for_bit():
    """One encoder for all the seeds: what one message set must not leak into the next."""
    encoder = codec.Encoder()
    for seed in range(40):
        rng = np.random.default_rng(seed)
        t = scalar(rng)
        contact = rng.random(6) < 0.5
        for sample in (ImuSample(t, floats(rng, 3), floats(rng, 3)),
                       AccelSample(t, int(rng.integers(0, 300)), floats(rng, 3)),
                       EncoderSample(t, floats(rng, 18)), FootSample(t, floats(rng, 6), contact)):
            topic, data = encoder.sample(sample)
            decoded = codec.decode_sample(topic, data)
            assert type(decoded) is type(sample)
            for name, value in vars(sample).items():
                same(getattr(decoded, name), value)

        estimate = random_estimate(rng, t)
        decoded = codec.decode_estimate(encoder.estimate(estimate))
        for name, value in vars(estimate).items():
            same(getattr(decoded, name), value)

        truth = Truth(t, floats(rng, 3), floats(rng, (3, 3)), floats(rng, 3), floats(rng, 3), floats(rng, 3),
                      floats(rng, 3), floats(rng, 18), floats(rng, 18), floats(rng, (6, 3)), floats(rng, (6, 3)),
                      floats(rng, 6), contact, floats(rng, 3))
        for name, value in codec.decode_truth_state(encoder.truth_state(truth))._asdict().items():
            same(value, getattr(truth, name))
        feet_t, feet, feet_contact = codec.decode_feet(encoder.feet(truth))
        same(feet_t, t)
        same(feet, truth.foot_positions)
        same(feet_contact, contact)

        contacts = FootContacts(floats(rng, (6, 3)), floats(rng, 6), floats(rng, (6, 3)), floats(rng, (6, 3)), contact)
        contacts_t, decoded_contacts = codec.decode_contacts(encoder.contacts(t, contacts))
        same(contacts_t, t)
        for name, value in contacts._asdict().items():
            same(getattr(decoded_contacts, name), value)

        polygon = floats(rng, (int(rng.integers(0, 7)), 2))     # no vertex at all included
        margin = scalar(rng)
        support = codec.decode_support(encoder.support(t, polygon, truth.com_position[:2], margin))
        same(support.t, t)
        same(support.polygon, polygon)
        same(support.com_projection, truth.com_position[:2])
        same(support.stability_margin, margin)

        command = Command(t, floats(rng, 6), ~contact, floats(rng, (6, 3)), floats(rng, 18), floats(rng, 3))
        for name, value in codec.decode_command(encoder.command(command))._asdict().items():
            same(value, getattr(command, name))


@pytest.mark.parametrize("t_ns", [0, 1, 999_999_999, 1_000_000_000, 61_000_000_123, 2**40])
def test_poses_and_transforms_come_back_bit_for_bit(t_ns):
    rng = np.random.default_rng(t_ns % 1000)
    encoder = codec.Encoder()
    for _ in range(20):
        position, quaternion = floats(rng, 3), floats(rng, 4)
        decoded_position, decoded_quaternion = codec.decode_pose(encoder.pose(t_ns, position, quaternion))
        same(decoded_position, position)
        same(decoded_quaternion, quaternion)
        (transform,) = FrameTransforms.FromString(encoder.transforms(t_ns, position, quaternion)).transforms
        assert (transform.timestamp.seconds * codec.NS_PER_S + transform.timestamp.nanos) == t_ns
        assert (transform.parent_frame_id, transform.child_frame_id) == (codec.WORLD_FRAME, codec.BODY_FRAME)
        same([transform.translation.x, transform.translation.y, transform.translation.z], position)
        same([transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w], quaternion)


def test_arrays_of_any_layout_are_written_row_major():
    matrix = np.arange(18.0).reshape(3, 6)
    encoder = codec.Encoder()
    for view in (matrix.T, matrix[::-1], np.asfortranarray(matrix), matrix.tolist()):
        _, data = encoder.sample(EncoderSample(0.5, view))
        same(codec.decode_sample("/sensors/encoders", data).positions, np.asarray(view, dtype=float).ravel())


def test_field_numbers_have_no_limit():
    """A message of 40 fields, numbered past the one-byte keys (16 and up), repeated and singular."""
    proto = descriptor_pb2.FileDescriptorProto(name="wide.proto", package="wide", syntax="proto3")
    message = proto.message_type.add(name="Wide")
    for number in range(1, 41):
        message.field.add(name=f"f{number}", number=number, type=descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
                          label=descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED if number % 2
                          else descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    wide = GetMessageClass(pool.Add(proto).message_types_by_name["Wide"])
    values = [np.arange(number, number + 3.0) if number % 2 else float(number) for number in range(1, 41)]
    decoded = wide.FromString(codec.MessageEncoder(wide).encode(values))
    for number, value in zip(range(1, 41), values):
        np.testing.assert_array_equal(getattr(decoded, f"f{number}"), value)
