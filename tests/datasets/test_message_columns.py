"""Columnar decoding of the dataset's messages (`datasets.message_columns`) against
protobuf's own value-by-value decoding."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass

from datasets import schemas
from datasets.message_columns import Ragged, message_columns


def _estimates(rng: np.random.Generator, count: int) -> list[bytes]:
    """Estimate messages with optional fields present or not and covariances of varying length."""
    payloads = []
    for k in range(count):
        message = schemas.EstimateMsg(t=0.001 * k, quaternion=rng.normal(size=4), roll=rng.normal(),
                                      attitude_cov=rng.normal(size=9 if k % 3 else 4))
        if k % 2:
            message.body_height = rng.normal()
        payloads.append(message.SerializeToString())
    return payloads


def test_every_field_equals_protobufs_own_decoding():
    payloads = _estimates(np.random.default_rng(3), 50)
    columns = message_columns(schemas.EstimateMsg, payloads)
    messages = [schemas.EstimateMsg.FromString(data) for data in payloads]
    np.testing.assert_array_equal(columns["t"], [m.t for m in messages])
    np.testing.assert_array_equal(columns["body_height"],
                                  [m.body_height if m.HasField("body_height") else np.nan for m in messages])
    covariances = columns["attitude_cov"]
    assert covariances.width() is None and covariances.matrix() is None
    np.testing.assert_array_equal(covariances.lengths, [len(m.attitude_cov) for m in messages])
    np.testing.assert_array_equal(covariances.values, [v for m in messages for v in m.attitude_cov])
    table = covariances.table(9)
    np.testing.assert_array_equal(table[0, :4], list(messages[0].attitude_cov))
    assert np.isnan(table[0, 4:]).all() and not np.isnan(table[1]).any()
    np.testing.assert_array_equal(columns["quaternion"].rows(2, 2).reshape(-1, 4), [m.quaternion for m in messages])


def test_bool_arrays_and_writable_values():
    payloads = [schemas.FootSampleMsg(t=k, normal_forces=np.full(6, k), contact=[k % 2 == 0] * 3 + [True] * 3)
                .SerializeToString() for k in range(4)]
    columns = message_columns(schemas.FootSampleMsg, payloads)
    contact = columns["contact"].matrix()
    assert contact.dtype == bool and contact.shape == (4, 6)
    np.testing.assert_array_equal(contact[:, 0], [True, False, True, False])
    forces = columns["normal_forces"].matrix()
    forces[0, 0] = -1.0                       # samples may be changed in place by whoever reads them
    assert forces.dtype == np.float64 and forces[3, 5] == 3.0


def test_no_messages():
    columns = message_columns(schemas.ImuSampleMsg, [])
    assert len(columns["t"]) == 0 and columns["accel"].rows(3).shape == (0, 3)


def _unpacked_imu_class() -> type:
    """ImuSample with the same field numbers, its arrays written unpacked (one tag per value)."""
    proto = descriptor_pb2.FileDescriptorProto(name="unpacked.proto", package="unpacked", syntax="proto2")
    message = proto.message_type.add(name="ImuSample")
    message.field.add(name="t", number=1, type=descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
                      label=descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL)
    for number, name in ((2, "accel"), (3, "gyro")):
        message.field.add(name=name, number=number, type=descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
                          label=descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED)
    return GetMessageClass(descriptor_pool.DescriptorPool().Add(proto).message_types_by_name["ImuSample"])


def test_unpacked_arrays_are_decoded_value_by_value():
    unpacked = _unpacked_imu_class()
    payloads = [unpacked(t=0.5 * k, accel=[k, 2.0, 3.0], gyro=[0.1, 0.2, k]).SerializeToString() for k in range(3)]
    assert payloads[0] != schemas.ImuSampleMsg.FromString(payloads[0]).SerializeToString()     # really unpacked
    columns = message_columns(schemas.ImuSampleMsg, payloads)
    np.testing.assert_array_equal(columns["accel"].matrix(), [[k, 2.0, 3.0] for k in range(3)])
    np.testing.assert_array_equal(columns["gyro"].matrix()[:, 2], [0, 1, 2])


def test_a_bool_not_encoded_as_one_byte_is_decoded_value_by_value():
    # Field 3 (contact), packed, values varint 2 and 1: both are `true` for protobuf.
    payload = schemas.FootSampleMsg(t=1.0).SerializeToString() + bytes([0x1A, 0x02, 0x02, 0x01])
    columns = message_columns(schemas.FootSampleMsg, [payload])
    np.testing.assert_array_equal(columns["contact"].matrix(), [[True, True]])


@pytest.mark.parametrize("width", [2, 4])
def test_table_pads_and_cuts(width):
    ragged = Ragged(np.arange(5, dtype=float), np.array([3, 0, 2]))
    table = ragged.table(width)
    assert table.shape == (3, width)
    np.testing.assert_array_equal(table[0, :min(3, width)], np.arange(min(3, width)))
    assert np.isnan(table[1]).all() and table[2, 0] == 3.0
