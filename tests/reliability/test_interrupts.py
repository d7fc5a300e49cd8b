"""Nothing lost: interrupts (real signals to a `testbed run` process) and two runs writing the same
file leave a valid MCAP under its final name, one line on stderr, and the documented exit code."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from datasets.reader import read_recording
from datasets.writer import OutputBusy, publish
from tests.reliability.cli_process import assert_one_line, finish, start, wait_for
from tests.datasets.conftest import run_rerun

pytestmark = pytest.mark.slow
WALK = ("run", "--terrain", "flat", "--gait", "tripod")


def assert_valid(path: Path) -> None:
    assert path.exists() and not path.with_name(path.name + ".partial").exists()
    check = run_rerun("mcap", "check", str(path))
    assert check.returncode == 0, check.stdout + check.stderr
    assert read_recording(path).truncated is None


def started_recording(path: Path, size: int = 50_000):
    partial = path.with_name(path.name + ".partial")
    return wait_for(lambda: partial.exists() and partial.stat().st_size > size, 120)


def test_two_runs_to_the_same_file_one_wins_the_other_says_so(tmp_path):
    out = tmp_path / "same.mcap"
    first = start(*WALK, "--duration", "15", "--seed", "1", "--out", str(out))
    started_recording(out, 0)
    # The first run holds still while the second starts: on a fast machine it would otherwise
    # finish before the second has started, and the second would only find the name taken.
    first.send_signal(signal.SIGSTOP)
    second = start(*WALK, "--duration", "2", "--seed", "2", "--out", str(out))
    try:
        status_2, _, err_2 = finish(second)
    finally:
        first.send_signal(signal.SIGCONT)
    status_1, _, err_1 = finish(first)
    assert (status_1, status_2) == (0, 1), (err_1, err_2)
    assert_one_line(err_1)
    assert_one_line(err_2)
    assert "being written by another process" in err_2
    assert_valid(out)
    assert read_recording(out).run_info()["seed"] == "1"


def test_a_name_taken_meanwhile_is_not_replaced_without_force(tmp_path):
    final, partial = tmp_path / "run.mcap", tmp_path / "run.mcap.partial"
    final.write_bytes(b"the other run's file")
    partial.write_bytes(b"this run's file")
    with pytest.raises(OutputBusy, match="kept as"):
        publish(partial, final, replace=False)
    assert final.read_bytes() == b"the other run's file" and partial.read_bytes() == b"this run's file"
    publish(partial, final, replace=True)
    assert final.read_bytes() == b"this run's file" and not partial.exists()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_mid_run_keeps_a_complete_file(tmp_path, signum):
    out = tmp_path / "stopped.mcap"
    process = start(*WALK, "--duration", "30", "--out", str(out))
    started_recording(out)
    process.send_signal(signum)
    status, stdout, err = finish(process)
    assert status == 130 and "interrupted at t =" in err
    assert_one_line(err)
    assert_valid(out)
    assert read_recording(out).outcome()["error"].startswith("interrupted")


def test_a_second_ctrl_c_during_the_shutdown_changes_nothing(tmp_path):
    out = tmp_path / "twice.mcap"
    process = start(*WALK, "--duration", "30", "--out", str(out))
    started_recording(out)
    process.send_signal(signal.SIGINT)
    for delay in (0.02, 0.05, 0.1):
        time.sleep(delay)
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    status, _, err = finish(process)
    assert status == 130
    assert_one_line(err)
    assert_valid(out)
    assert read_recording(out).metrics()["sim_time_s"] > 0


def test_a_ctrl_c_as_the_file_appears_leaves_no_empty_file(tmp_path):
    out = tmp_path / "early.mcap"
    process = start(*WALK, "--duration", "5", "--out", str(out))
    wait_for(out.with_name(out.name + ".partial").exists, 120, interval=0.0005)
    process.send_signal(signal.SIGINT)
    status, _, err = finish(process)
    assert status == 130
    assert_one_line(err)
    assert_valid(out)


def loads_numpy(process) -> bool:
    """Whether the process has loaded numpy's library: the command line's imports are under way
    (it installs its Ctrl-C handler before any of them)."""
    return "numpy" in Path(f"/proc/{process.pid}/maps").read_text()


def test_a_ctrl_c_during_the_imports_exits_130_without_a_traceback(tmp_path):
    process = start(*WALK, "--duration", "1", "--out", str(tmp_path / "x.mcap"))
    wait_for(lambda: loads_numpy(process), 60)
    process.send_signal(signal.SIGINT)
    status, _, err = finish(process)
    assert status == 130 and err.strip() == "testbed: interrupted"


def test_a_ctrl_c_after_the_run_has_stopped_changes_nothing(tmp_path, monkeypatch):
    """A real SIGINT while the finished run closes its file (in this process): held, then dropped."""
    from datasets.recorder import McapRecorder
    from tests.reliability.cli_process import run_main

    finish = McapRecorder.finish

    def interrupted_finish(self, metrics, error):
        signal.raise_signal(signal.SIGINT)
        finish(self, metrics, error)

    monkeypatch.setattr(McapRecorder, "finish", interrupted_finish)
    out = tmp_path / "done.mcap"
    status, stdout, err = run_main(["run", "--terrain", "flat", "--duration", "1.2", "--out", out])
    assert status == 0 and err == "" and f"recorded {out}" in stdout
    assert_valid(out)
    assert read_recording(out).outcome()["error"] == ""
