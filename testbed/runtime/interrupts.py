"""Stopping a run from outside: Ctrl-C (SIGINT), and SIGTERM and SIGHUP treated the same.

`treat_stop_signals_as_interrupt` makes the first of the three raise KeyboardInterrupt in the main
thread, and the later ones ignored.
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
    """The first of SIGINT, SIGTERM and SIGHUP raises KeyboardInterrupt (also when SIGINT was
    inherited ignored, as by a run started in the background by a non-interactive shell); the
    ones after it are ignored: the command is stopping, and an exception raised anywhere in its
    shutdown (a finaliser, a `__del__`) would only print a traceback."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, _interrupt_once)


def _interrupt_once(signum: int, frame) -> None:
    for stop_signal in STOP_SIGNALS:
        signal.signal(stop_signal, signal.SIG_IGN)
    raise KeyboardInterrupt


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
