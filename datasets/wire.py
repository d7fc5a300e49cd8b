"""Protobuf's wire format, written directly for the dataset's per-step messages.

Recording serialises about five messages per physics step. Filling a reused protobuf message
(`m.field[:] = array.tolist()`) and calling SerializeToString cost 1.2 to 9 us a message; the
same bytes put together from `ndarray.tobytes()` and precomputed field keys cost about a third.
The bytes are protobuf's own, byte for byte (tests/datasets/test_wire.py checks every message
type against SerializeToString, zeros of both signs, NaN, empty and absent fields included), so
any protobuf reader decodes them as before.

What protobuf (proto3) writes, and so what this module writes: fields in field-number order; a
singular number only when its bits are not all zero (0.0 is left out, -0.0 is written); a proto3
`optional` number whenever it is set; a repeated number field packed, left out when empty; a
sub-message whenever it is set, even empty.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from operator import attrgetter
from typing import Any

import numpy as np

VARINT, FIXED64, LENGTH_DELIMITED = 0, 1, 2
_DOUBLE = struct.Struct("<d").pack
_ZERO_DOUBLE = bytes(8)
_FLOAT64, _BOOL = np.dtype(np.float64), np.dtype(np.bool_)


def _varint(value: int) -> bytes:
    out = bytearray()
    while value >= 128:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


_SHORT_VARINTS = list(map(_varint, range(4096)))     # lengths and small counts, looked up


def varint(value: int) -> bytes:
    """Base-128 varint of a non-negative integer."""
    return _SHORT_VARINTS[value] if value < 4096 else _varint(value)


def key(number: int, wire_type: int) -> bytes:
    return varint(number << 3 | wire_type)


def double(field_key: bytes, value: float) -> bytes:
    """A singular double: absent when its bits are all zero."""
    data = _DOUBLE(value)
    return b"" if data == _ZERO_DOUBLE else field_key + data


def unsigned(field_key: bytes, value: int) -> bytes:
    """A singular non-negative integer (uint32, or an int64 / int32 that is never negative)."""
    return field_key + varint(value) if value else b""


def length_delimited(field_key: bytes, data: bytes) -> bytes:
    """A sub-message (always present) or a string's bytes."""
    return field_key + varint(len(data)) + data


def string(field_key: bytes, text: str) -> bytes:
    return length_delimited(field_key, text.encode()) if text else b""


def doubles(field_key: bytes, values: Any) -> bytes:
    """A packed repeated double of an array of any shape, row-major; absent when empty."""
    data = np.asarray(values, dtype=float).tobytes()
    return field_key + varint(len(data)) + data if data else b""


# Field kinds of a Layout, from datasets.schemas.MESSAGES' (type, kind).
_DOUBLE_FIELD, _OPTIONAL_DOUBLE, _DOUBLES, _BOOLS, _UNSIGNED = range(5)
_KINDS = {("double", "one"): (_DOUBLE_FIELD, FIXED64), ("double", "maybe"): (_OPTIONAL_DOUBLE, FIXED64),
          ("double", "many"): (_DOUBLES, LENGTH_DELIMITED), ("bool", "many"): (_BOOLS, LENGTH_DELIMITED),
          ("uint32", "one"): (_UNSIGNED, VARINT)}


class Layout:
    """The wire format of one message of `datasets.schemas.MESSAGES`. `encode(values)` takes the
    field values in field order (None for an absent optional or an empty repeated field; arrays
    of any shape, row-major), `encode_fields_of(item)` the attributes named as the fields.

    One loop over the fields with the kinds inline: a function call per field would cost as much
    as writing the field."""

    def __init__(self, fields: Sequence[tuple[str, str, str]]):
        self.names = tuple(name for name, _, _ in fields)
        self._values_of = attrgetter(*self.names)
        self._fields = []
        for number, (_, type_name, kind) in enumerate(fields, start=1):
            field_kind, wire_type = _KINDS[type_name, kind]
            self._fields.append((field_kind, key(number, wire_type)))

    def encode_fields_of(self, item: Any) -> bytes:
        return self.encode(self._values_of(item))

    def encode_fields_of_many(self, items: Sequence[Any]) -> list[bytes]:
        return self.encode_many(list(map(self._values_of, items)))

    def encode_many(self, messages: Sequence[Sequence[Any]]) -> list[bytes]:
        """`encode` of each message's values, vectorised with numpy over the messages when each
        field is present in all of them or in none, with as many values in each (otherwise one
        by one): per field, one array of all the messages and one structured-array copy instead
        of a few Python operations per field and message."""
        rows = _uniform_rows(self._fields, messages) if len(messages) >= _FEWEST_TO_VECTORISE else None
        if rows is None:
            return [self.encode(values) for values in messages]
        data, size = rows.tobytes(), rows.dtype.itemsize
        return [data[start:start + size] for start in range(0, len(data), size)]

    def encode(self, values: Sequence[Any]) -> bytes:
        parts: list[bytes] = []
        for (kind, field_key), value in zip(self._fields, values):
            if kind == _DOUBLES or kind == _BOOLS:
                if value is None:
                    continue
                dtype = _FLOAT64 if kind == _DOUBLES else _BOOL
                if type(value) is not np.ndarray or value.dtype is not dtype:
                    value = np.asarray(value, dtype=dtype)
                data = value.tobytes()      # row-major, little-endian doubles or one byte per bool
                if data:
                    parts += (field_key, varint(len(data)), data)
            elif kind == _DOUBLE_FIELD:
                data = _DOUBLE(value)
                if data != _ZERO_DOUBLE:
                    parts += (field_key, data)
            elif kind == _OPTIONAL_DOUBLE:
                if value is not None:
                    parts += (field_key, _DOUBLE(value))
            elif value:
                parts += (field_key, varint(value))
        return b"".join(parts)


_FEWEST_TO_VECTORISE = 8


def _uniform_rows(fields: list[tuple[int, bytes]], messages: Sequence[Sequence[Any]]) -> np.ndarray | None:
    """One structured-array row per message, each the message's bytes, or None when the messages
    do not share one layout (a field present in some only, repeated fields of different lengths,
    or an integer field)."""
    columns = list(zip(*messages))
    layout, values = [], []
    for index, ((kind, field_key), column) in enumerate(zip(fields, columns)):
        if kind == _UNSIGNED:
            return None
        if kind == _DOUBLES or kind == _BOOLS or kind == _OPTIONAL_DOUBLE:
            absent = [value is None for value in column]
            if any(absent):
                if all(absent):
                    continue
                return None
        dtype = _BOOL if kind == _BOOLS else _FLOAT64
        try:
            array = np.array(column, dtype=dtype).reshape(len(column), -1)
        except ValueError:          # repeated fields of different lengths
            return None
        if kind == _DOUBLE_FIELD:
            written = array.view(np.uint64)[:, 0] != 0     # a singular double is left out when its bits are all zero
            if not written.all():
                if written.any():
                    return None
                continue
        count = array.shape[1]
        if count == 0:
            continue
        repeated = kind == _DOUBLES or kind == _BOOLS
        prefix = field_key + varint(array.nbytes // len(array)) if repeated else field_key
        layout += [(f"key{index}", np.uint8, (len(prefix),)),
                   (f"value{index}", "<f8" if dtype is _FLOAT64 else np.uint8, (count,))]
        values += [np.frombuffer(prefix, np.uint8), array]
    if not layout:
        return None
    rows = np.empty(len(messages), np.dtype(layout))
    for (name, _, _), value in zip(layout, values):
        rows[name] = value
    return rows
