"""Bounded memory (`make bench`): the peak resident memory of a 600 s tripod walk, recorded, stays under
600 MB and within 10 % of a 60 s walk's: nothing is kept per tick. Each run is a `testbed run` in a
process of its own, measured by `resource.getrusage` (RUSAGE_CHILDREN: the largest of the run and
its writer process). Skipped unless the bench marker is selected (`pytest -m bench`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from testbed.tools import bench_report

pytestmark = pytest.mark.bench
ROOT = Path(__file__).resolve().parents[2]
LIMIT_MB = 600.0
MEASURE = """
import json, resource, subprocess, sys
status = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
print(json.dumps({"status": status.returncode, "stderr": status.stderr[-500:],
                  "peak_kb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss}))
"""


def peak_rss_mb(duration: float, out: Path) -> float:
    command = [sys.executable, "-c", MEASURE, sys.executable, "-m", "testbed.tools.cli", "run", "--terrain", "flat",
               "--gait", "tripod", "--turn-rate", "0.2", "--duration", str(duration), "--out", str(out), "--metrics", str(out.with_suffix(".json"))]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = json.loads(subprocess.run(command, capture_output=True, text=True, check=True, env=env).stdout)
    assert result["status"] == 0, result["stderr"]
    metrics = json.loads(out.with_suffix(".json").read_text())
    assert metrics["sim_time_s"] >= duration - 1e-6 and not metrics["fell"], metrics     # walked the whole time
    return result["peak_kb"] / 1024.0


def test_a_600_s_walk_peaks_under_600_mb_and_as_high_as_a_60_s_walk(request, tmp_path, capsys):
    if "bench" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("a benchmark: run it with -m bench (make bench)")
    peak_60 = peak_rss_mb(60.0, tmp_path / "walk60.mcap")
    peak_600 = peak_rss_mb(600.0, tmp_path / "walk600.mcap")
    growth = peak_600 / peak_60 - 1.0
    line = f"peak RSS: 60 s walk {peak_60:.0f} MB, 600 s walk {peak_600:.0f} MB ({100 * growth:+.1f} %)"
    with capsys.disabled():
        print(f"\n{line}")
    bench_report.write_fragment("memory.md", (
        "## Memory: a run's peak independent of its length (issue 19)\n\n"
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, flat terrain, tripod walking in a circle (turn rate 0.2 rad/s, so as to stay on the ground plate), default estimator, recorded: {line}. "
        f"Targets: under {LIMIT_MB:.0f} MB, within 10 %.\n"))
    assert peak_600 < LIMIT_MB
    assert abs(growth) < 0.10
