"""A Dask cluster that fails under a sweep: all workers gone, the scheduler killed, a worker that
returns forged index rows. The sweep stops within --connect-timeout with exit 1, one line saying
what happened, and every finished run kept in its index."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from testbed.tools import sweep
from tests.testbed.test_sweep import ESTIMATOR, ONE_THREAD, TESTBED, dask_cluster, index_rows, partials, wait_for

pytestmark = pytest.mark.slow
TIMEOUT = "3"


def sweep_process(address: str, folder: Path, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([TESTBED, "sweep", "--terrains", "flat", "--seeds", "4", "--estimators", ESTIMATOR,
                             "--duration", "8", "--scheduler", address, "--connect-timeout", TIMEOUT,
                             "--out", str(folder)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)


@pytest.mark.parametrize("killed", ["workers", "scheduler"])
def test_a_cluster_that_goes_away_stops_the_sweep_in_time(tmp_path, killed):
    folder = tmp_path / "runs"
    with dask_cluster(tmp_path, {**os.environ, **ONE_THREAD}) as (address, workers):
        process = sweep_process(address, folder, tmp_path)
        try:
            wait_for(lambda: partials(folder), 180, "a run in flight", process)
            time.sleep(1.0)
            if killed == "workers":
                for worker in workers.values():
                    worker.kill()
            else:
                scheduler = [p for p in _children_named("scheduler")]
                for pid in scheduler:
                    os.kill(pid, 9)
            stopped = time.monotonic()
            out, err = process.communicate(timeout=120)
        finally:
            if process.poll() is None:
                process.kill()
        waited = time.monotonic() - stopped
    assert process.returncode == 1, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("testbed: sweep stopped: ") and "index" in last and "resume" in last
    if killed == "workers":
        assert "has had no worker for 3 s" in last
        assert waited < float(TIMEOUT) + 30
    else:
        assert "scheduler" in last and "is gone" in last and "worker died" not in err
    if (folder / sweep.INDEX_FILE).exists():        # the runs finished before the fault are kept
        assert all(row["error"] == "" for row in index_rows(folder).values())


def _children_named(word: str) -> list[int]:
    import psutil
    return [p.pid for p in psutil.process_iter(["cmdline"])
            if p.info["cmdline"] and len(p.info["cmdline"]) > 2 and p.info["cmdline"][1].endswith("dask")
            and p.info["cmdline"][2] == word and p.pid != os.getpid()]


def spec(tmp_path: Path) -> sweep.RunSpec:
    return sweep.RunSpec("flat_seed000_ekf_default", str(tmp_path / "flat_seed000_ekf_default.mcap"), {}, "0123abcd",
                         "default")


def good_row(run: sweep.RunSpec) -> dict:
    return {"name": run.name, "file": Path(run.path).name, "config_hash": run.config_hash, "seed": 0,
            "roll_rmse_deg": 0.4, "fell": False, "error": "", "slope_error_deg": None}


@pytest.mark.parametrize("forgery", [
    {"file": "../../../../etc/passwd"},
    {"file": "/etc/passwd"},
    {"name": "step_seed001_ekf_default"},
    {"config_hash": "ffffffffffffffff"},
    {"roll_rmse_deg": [1, 2]},
    {"roll_rmse_deg": object()},
    {"bad name": 1},
])
def test_a_forged_index_row_is_refused(tmp_path, forgery):
    run = spec(tmp_path)
    assert sweep.checked_row(good_row(run), run) == good_row(run)
    with pytest.raises(sweep.InvalidRow):
        sweep.checked_row({**good_row(run), **forgery}, run)
    with pytest.raises(sweep.InvalidRow):
        sweep.checked_row([good_row(run)], run)
