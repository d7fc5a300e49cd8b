"""Stopping a run from outside: Ctrl-C (SIGINT), and SIGTERM and SIGHUP treated the same.

`treat_stop_signals_as_interrupt` makes all three raise KeyboardInterrupt in the main thread.
`held_interrupts` keeps them out of a stretch of work that must not be cut (closing the run's
files): they wait, blocked, until it ends, and are then dropped, because the work they would have
stopped is done.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def treat_stop_signals_as_interrupt() -> None:
    """SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt (also when SIGINT was inherited ignored,
    as by a run started in the background by a non-interactive shell)."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.default_int_handler)


@contextmanager
def held_interrupts() -> Iterator[None]:
    """Block the stop signals for the duration of the block, then drop those that came."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        while signal.sigtimedwait([s for s in STOP_SIGNALS if s not in previous], 0) is not None:
            pass
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
