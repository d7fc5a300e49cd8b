"""Columns of the dataset's own protobuf messages: each field's values over many messages as one
numpy array.

protobuf's Python API hands a repeated field over one Python object per value. The dataset's
arrays are packed repeated fields, whose wire form is one length-delimited run of little-endian
doubles (one byte per bool): the wire form of a `bytes` field. So the messages are parsed by
protobuf itself with a view of their schema in which each array is a `bytes` field under the same
number (`schemas.PACKED_VIEWS`), and the bytes of all the messages become one array through
`numpy.frombuffer`, with no Python object per value. Messages whose arrays are not packed (legal
protobuf, though no writer of this testbed makes them) are decoded value by value instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import chain
from operator import attrgetter

import numpy as np

from datasets import schemas

_SCALAR_DTYPES = {"double": float, "bool": bool, "uint32": np.int64, "int64": np.int64, "string": object}
_ARRAY_DTYPES = {"double": np.dtype("<f8"), "bool": np.dtype(np.uint8)}


@dataclass(frozen=True)
class Ragged:
    """A repeated field over N messages: all values in message order, and how many each holds."""
    values: np.ndarray          # (sum(lengths),)
    lengths: np.ndarray         # (N,) int64

    def width(self) -> int | None:
        """The number of values every message holds, or None when they differ."""
        if not len(self.lengths):
            return 0
        first = int(self.lengths[0])
        return first if np.all(self.lengths == first) else None

    def matrix(self) -> np.ndarray | None:
        """(N, width) when every message holds the same number of values, else None."""
        width = self.width()
        return None if width is None else self.values.reshape(len(self.lengths), width)

    def rows(self, *shape: int) -> np.ndarray | None:
        """(N, *shape), or None unless every message holds prod(shape) values."""
        expected = int(np.prod(shape))
        if len(self.lengths) and self.width() != expected:
            return None
        return self.values.reshape(len(self.lengths), *shape)

    def table(self, width: int) -> np.ndarray:
        """(N, width): `matrix()` when every message holds `width` values; else float, NaN where a
        message holds fewer (values beyond `width` dropped)."""
        if self.width() == width:
            return self.matrix()
        table = np.full((len(self.lengths), width), np.nan)
        row_of_value = np.repeat(np.arange(len(self.lengths)), self.lengths)
        column_of_value = np.arange(len(self.values)) - np.repeat(np.cumsum(self.lengths) - self.lengths, self.lengths)
        kept = column_of_value < width
        table[row_of_value[kept], column_of_value[kept]] = self.values[kept]
        return table


def message_columns(message_class: type, payloads: Sequence[bytes]) -> dict[str, np.ndarray | Ragged]:
    """Every field of the dataset message `message_class` over the messages `payloads`: a singular
    field as an (N,) array (an absent optional one as NaN), a repeated one as `Ragged`."""
    name = message_class.DESCRIPTOR.name
    view = schemas.PACKED_VIEWS[name]
    messages = list(map(view.FromString, payloads))
    if messages and not _packed(message_class, payloads[0], messages[0]):
        return _columns_value_by_value(message_class, payloads)
    columns: dict[str, np.ndarray | Ragged] = {}
    for field, type_name, kind in schemas.MESSAGES[name]:
        if kind == "many":
            columns[field] = _packed_column(list(map(attrgetter(field), messages)), type_name)
        else:
            columns[field] = _scalar_column(messages, field, type_name, kind)
    if any(column is None for column in columns.values()):
        return _columns_value_by_value(message_class, payloads)
    return columns


def _packed(message_class: type, payload: bytes, view) -> bool:
    """Whether the view reads this message's arrays whole (they are packed)."""
    message = message_class.FromString(payload)
    return all(len(getattr(view, field)) == len(getattr(message, field)) * _ARRAY_DTYPES[type_name].itemsize
               for field, type_name, kind in schemas.MESSAGES[message_class.DESCRIPTOR.name] if kind == "many")


def _packed_column(runs: list[bytes], type_name: str) -> Ragged | None:
    """The values of one packed field per message; None when a bool is not encoded as one byte 0 or 1."""
    dtype = _ARRAY_DTYPES[type_name]
    lengths = np.fromiter(map(len, runs), dtype=np.int64, count=len(runs))
    if np.any(lengths % dtype.itemsize):
        return None
    values = np.frombuffer(bytearray().join(runs), dtype=dtype)      # a bytearray: writable arrays
    if type_name == "bool":
        if np.any(values > 1):
            return None
        return Ragged(values.view(bool), lengths)
    return Ragged(values.astype(float, copy=False), lengths // dtype.itemsize)


def _scalar_column(messages: list, field: str, type_name: str, kind: str) -> np.ndarray:
    if kind == "maybe":
        return np.array([getattr(m, field) if m.HasField(field) else np.nan for m in messages], dtype=float)
    return np.fromiter(map(attrgetter(field), messages), dtype=_SCALAR_DTYPES[type_name], count=len(messages))


def _columns_value_by_value(message_class: type, payloads: Sequence[bytes]) -> dict[str, np.ndarray | Ragged]:
    messages = list(map(message_class.FromString, payloads))
    columns: dict[str, np.ndarray | Ragged] = {}
    for field, type_name, kind in schemas.MESSAGES[message_class.DESCRIPTOR.name]:
        if kind != "many":
            columns[field] = _scalar_column(messages, field, type_name, kind)
            continue
        rows = list(map(attrgetter(field), messages))
        lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
        values = np.fromiter(chain.from_iterable(rows), dtype=_SCALAR_DTYPES[type_name], count=int(lengths.sum()))
        columns[field] = Ragged(values, lengths)
    return columns
