"""Settings and state for compiled kernels as numpy structured records: fields by name, never by
position. A one-element array of records passes to a numba kernel as cheaply as a plain array
(a NamedTuple costs several times more per call), and the kernel reads `array[0].field`."""

from __future__ import annotations

import numpy as np


def one_record(dtype: np.dtype, **fields) -> np.ndarray:
    """A one-element array of `dtype` records with every field given by name."""
    missing, unknown = set(dtype.names) - set(fields), set(fields) - set(dtype.names)
    if missing or unknown:
        raise TypeError(f"record fields missing: {sorted(missing)}, unknown: {sorted(unknown)}")
    record = np.zeros(1, dtype)
    for name, value in fields.items():
        record[name] = value
    return record
