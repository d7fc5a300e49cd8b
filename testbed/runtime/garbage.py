"""The cyclic garbage collector during long loops that keep many objects (a run, a replay)."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def older_objects_left_alone() -> Iterator[None]:
    """Within the block the cyclic garbage collector leaves the objects that exist before it alone
    (`gc.freeze`): the full collections that the block's many kept objects trigger would otherwise
    also scan every object of the libraries loaded, each time (about 0.15 s each). The block's own
    garbage is still collected. Where objects are frozen already (by the program, before forking
    its workers), nothing changes, and they stay frozen after the block."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
