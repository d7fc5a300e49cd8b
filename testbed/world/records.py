"""Settings and state for compiled kernels as numpy structured records: fields by name, never by
position.

A record array reaches a kernel as its raw bytes (`raw`), which the kernel views back as records
(`raw.view(DTYPE)`; `the_record` for a one-element array). numba recognises a plain byte array's
type in its dispatcher's fast path, while a structured array's type is worked out in Python at
every call, several times the cost of the kernel's arithmetic here. A byte array of another
record's size fails the view or `the_record`: the record types in this package have distinct sizes.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def one_record(dtype: np.dtype, **fields) -> np.ndarray:
    """A one-element array of `dtype` records with every field given by name."""
    missing, unknown = set(dtype.names) - set(fields), set(fields) - set(dtype.names)
    if missing or unknown:
        raise TypeError(f"record fields missing: {sorted(missing)}, unknown: {sorted(unknown)}")
    record = np.zeros(1, dtype)
    for name, value in fields.items():
        record[name] = value
    return record


def raw(records: np.ndarray) -> np.ndarray:
    """The bytes of a record array (a view: kernels that change them change the records)."""
    return np.ascontiguousarray(records).view(np.uint8)


@njit(cache=True)
def the_record(records):
    """The one record of a one-element record array."""
    if len(records) != 1:
        raise ValueError("a kernel was given the bytes of another record type")
    return records[0]
