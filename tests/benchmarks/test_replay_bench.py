"""Speed of offline replay (`make bench`, `pytest -m bench`): replaying a 60 s walk takes at most
1/50 of its simulated time through `vqf` and at most 1/30 through `ekf` (issue #17 item 6).

The walk is recorded once and kept under pytest's temporary root for later sessions. The machine
may be shared: each figure is the best of a few replays, wall and CPU time are both printed with
the load average, and the targets are reported as met or not without failing the test on time.
"""

from __future__ import annotations

import os
import time

import pytest

import testbed
from datasets.reader import read_description
from datasets.replay import replay
from testbed.model.errors import UserError

pytestmark = pytest.mark.bench
WALK = {"run": {"terrain": "flat", "gait": "tripod", "estimator": "ekf", "duration": 60.0}}
TARGET_RATIO = {"vqf": 1 / 50, "ekf": 1 / 30}       # replay wall time / simulated time
REPEATS = 3


@pytest.fixture(scope="module")
def walk60(tmp_path_factory):
    path = tmp_path_factory.getbasetemp().parent / "replay-bench-walk60.mcap"
    if not recorded_by_this_version(path):
        partial = path.with_suffix(".recording.mcap")
        testbed.run(WALK, out=partial)
        partial.replace(path)
    return path


def recorded_by_this_version(path) -> bool:
    """Whether the kept walk exists and its config reads with this testbed's keys."""
    try:
        read_description(path).config()
    except UserError:
        return False
    return True


@pytest.mark.parametrize("estimator", sorted(TARGET_RATIO))
def test_replay_of_a_60_s_walk(walk60, estimator, capsys):
    figures = []
    for _ in range(REPEATS):
        wall, cpu = time.perf_counter(), time.process_time()
        result = replay(walk60, estimator)
        figures.append((time.perf_counter() - wall, time.process_time() - cpu))
    wall, cpu = min(figures)
    sim_time = result.metrics["sim_time_s"]
    assert sim_time == pytest.approx(60.0, abs=0.01) and result.metrics["roll_rmse_deg"] is not None
    ratio, target = wall / sim_time, TARGET_RATIO[estimator]
    with capsys.disabled():
        print(f"\nreplay of a {sim_time:.0f} s walk through {estimator}: wall {wall:.3f} s (1/{1 / ratio:.1f} of "
              f"simulated time), CPU {cpu:.3f} s (1/{sim_time / cpu:.1f}); target 1/{1 / target:.0f}: "
              f"{'met' if ratio <= target else 'NOT met'} (best of {REPEATS}, load {os.getloadavg()[0]:.1f})")
