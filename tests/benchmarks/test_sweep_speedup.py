"""Sweep speed-up (`make bench`): the same sweep of 12 runs of 20 s on 1 and on 2 local workers.

Prints the wall times, the speed-up, the mean wall time of one run in each sweep (contention shows
there) and the machine's load average, then checks the issue's target: 2 workers at least 1.7
times faster than 1. The figures depend on the machine being otherwise idle: read the load printed
beside them. The fixed cost of a sweep (starting the workers, about 2 s) bounds the speed-up of
short sweeps (Amdahl): the grid is long enough for it to matter little. Skipped unless the bench
marker is selected (`pytest -m bench`).
"""

from __future__ import annotations

import os
import time

import pyarrow.parquet as pq
import pytest

from testbed.tools import bench_report, sweep
from testbed.tools.cli import main

pytestmark = pytest.mark.bench

GRID = ["--terrains", "flat,step", "--seeds", "3", "--estimators", "ekf,vqf", "--duration", "20"]
RUNS = 2 * 3 * 2
TARGET = 1.7


def timed_sweep(folder, workers: int) -> tuple[float, float, float]:
    """(wall time of the whole sweep, mean wall time and mean CPU time of one run inside it)."""
    started = time.perf_counter()
    assert main(["sweep", *GRID, "--workers", str(workers), "--out", str(folder)]) == 0
    wall = time.perf_counter() - started
    index = pq.read_table(folder / sweep.INDEX_FILE)
    elapsed, cpu = index.column("elapsed_s").to_pylist(), index.column("cpu_s").to_pylist()
    assert len(elapsed) == RUNS
    return wall, sum(elapsed) / RUNS, sum(cpu) / RUNS


def test_two_local_workers_are_at_least_1_7_times_faster_than_one(tmp_path, request, capsys):
    if "bench" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("a benchmark: run it with -m bench (make bench)")
    load_before = os.getloadavg()
    one, one_run, one_cpu = timed_sweep(tmp_path / "one", 1)
    two, two_run, two_cpu = timed_sweep(tmp_path / "two", 2)
    speedup = one / two
    # A run's wall time above its CPU time is time spent waiting for a core: other work.
    line = (f"sweep of {RUNS} runs x 20 s simulated on {os.cpu_count()} CPUs: "
            f"1 worker {one:.1f} s (a run: {one_run:.2f} s wall, {one_cpu:.2f} s CPU), "
            f"2 workers {two:.1f} s (a run: {two_run:.2f} s wall, {two_cpu:.2f} s CPU): speed-up x{speedup:.2f}; "
            f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after")
    with capsys.disabled():
        print("\n" + line)
    bench_report.write_fragment("speed_sweep.md", (
        "## Speed: sweeps on local workers (issue 8)\n\n"
        f"`testbed sweep {' '.join(GRID)}` on 1 and on 2 workers, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}. Target: 2 workers at least {TARGET} times faster.\n\n"
        f"{line}\n"))
    assert speedup >= TARGET, (f"2 workers only x{speedup:.2f} faster than 1 (load average "
                               f"{load_before[0]:.2f} before the benchmark: other work shares the CPUs)")
