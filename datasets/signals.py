"""Keep Ctrl-C out of the middle of an MCAP write.

A KeyboardInterrupt raised inside the mcap writer (between a message and its index entry, or
in the middle of a chunk) would leave a file that `finish` cannot close validly. Inside
`sigint_deferred()` a SIGINT is only noted; it is delivered to the previous handler when the block
ends, so the run loop still stops at once and its `finish` call sees a consistent writer.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def sigint_deferred() -> Iterator[None]:
    previous = signal.getsignal(signal.SIGINT)
    # Python runs signal handlers in the main thread only, and cannot restore a handler that was
    # installed outside Python (getsignal gives None): nothing to defer then.
    if threading.current_thread() is not threading.main_thread() or previous is None:
        yield
        return
    received = []
    signal.signal(signal.SIGINT, lambda signum, frame: received.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            _deliver(previous, received[-1])


def _deliver(handler, frame) -> None:
    if callable(handler):
        handler(signal.SIGINT, frame)
    elif handler != signal.SIG_IGN:
        signal.raise_signal(signal.SIGINT)   # SIG_DFL: the default action
