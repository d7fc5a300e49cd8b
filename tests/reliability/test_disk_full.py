"""A full disk: every command that writes exits 1 with one line, leaves no empty file, and keeps
what it wrote before. Runs on a small tmpfs, so only as root; skipped otherwise."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from datasets.recorder import McapRecorder
from testbed.tools import sweep
from tests.reliability import damaged
from tests.reliability.cli_process import run_main


@pytest.fixture
def small_disk(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    folder = tmp_path / "small"
    folder.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(folder)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    yield folder
    subprocess.run(["umount", str(folder)], check=False)


def fill(folder: Path, leave: int = 0) -> None:
    """Fill the disk, leaving about `leave` bytes."""
    stat = os.statvfs(folder)
    (folder / "filler").write_bytes(bytes(max(0, stat.f_bavail * stat.f_frsize - leave)))


def assert_no_empty_files(folder: Path) -> None:
    empty = [path.name for path in folder.rglob("*") if path.is_file() and path.stat().st_size == 0
             and path.name != "filler"]
    assert not empty, empty


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    return damaged.record_run(tmp_path_factory.mktemp("recorded") / "run.mcap")


def test_a_run_on_a_full_disk(small_disk):
    status, _, err = run_main(["run", "--terrain", "flat", "--gait", "tripod", "--duration", "10",
                               "--out", small_disk / "r.mcap"])
    assert status == 1 and "No space left on device" in err
    assert_no_empty_files(small_disk)


@pytest.mark.parametrize("argv", [
    ["replay", "{recorded}", "--estimator", "complementary", "--out", "{disk}/r.mcap"],
    ["replay", "{recorded}", "--estimator", "complementary", "--metrics", "{disk}/m.json"],
    ["view", "{recorded}", "--rrd", "{disk}/v.rrd"],
    ["export-urdf", "{disk}/robot.urdf"],
])
def test_the_other_writers_on_a_full_disk(small_disk, recorded, argv):
    fill(small_disk, leave=2048)
    status, _, err = run_main([arg.format(recorded=recorded, disk=small_disk) for arg in argv])
    assert status == 1 and "No space left on device" in err, err
    assert_no_empty_files(small_disk)
    assert sorted(path.name for path in small_disk.iterdir()) == ["filler"]


def test_a_sweep_index_on_a_full_disk_keeps_the_last_saved_index(small_disk):
    index = sweep.Index(small_disk)
    index.add({"name": "a", "file": "a.mcap", "config_hash": "1", "seed": 0})
    index.save()
    saved = (small_disk / sweep.INDEX_FILE).read_bytes()
    fill(small_disk)
    index.add({"name": "b", "file": "b.mcap", "config_hash": "2", "seed": 1, "note": "x" * 100_000})
    with pytest.raises(OSError):
        index.save()
    assert (small_disk / sweep.INDEX_FILE).read_bytes() == saved
    assert_no_empty_files(small_disk)
