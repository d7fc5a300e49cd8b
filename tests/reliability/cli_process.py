"""The `testbed` command line in a process of its own, for tests that send it real signals."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def start(*args: str, cwd: Path | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "testbed.tools.cli", *args], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def finish(process: subprocess.Popen, timeout: float = 120.0) -> tuple[int, str, str]:
    out, err = process.communicate(timeout=timeout)
    return process.returncode, out, err


def wait_for(condition, timeout: float, interval: float = 0.001):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError("timed out")


def assert_one_line(err: str) -> None:
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) <= 1, err


def run_main(argv: list[str]) -> tuple[int, str, str]:
    """`testbed ARGV` in this process: exit code, stdout, stderr (one line at most, no traceback)."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from testbed.tools import cli

    out, err = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        status = cli.main([str(arg) for arg in argv])
    lines = [line for line in err.getvalue().splitlines() if not line.startswith("testbed: warning:")]
    assert "Traceback" not in err.getvalue() and len(lines) <= 1, err.getvalue()
    assert "testbed: failed:" not in err.getvalue(), err.getvalue()
    return status, out.getvalue(), err.getvalue()
