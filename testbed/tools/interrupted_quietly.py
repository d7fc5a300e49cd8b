"""Ctrl-C while the command line is still importing its libraries (a second or two): exit 130
with one line, not a traceback through the import machinery. `testbed.tools.cli.main` then
installs the handlers of the run."""

from __future__ import annotations

import os
import signal
import sys
import threading


def during_imports(as_main: bool) -> None:
    """Only for the `testbed` command (`as_main` under `python -m`), never when imported by a program."""
    if not is_command(as_main):
        return
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(signum, _exit_interrupted)


def is_command(as_main: bool) -> bool:
    """Whether this process is the `testbed` command (or `python -m testbed.tools.cli`)."""
    return as_main or os.path.basename(sys.argv[0]) == "testbed"


def _exit_interrupted(signum, frame) -> None:
    os.write(2, b"testbed: interrupted\n")
    os._exit(130)
