"""`testbed run --rerun-live`: the run streams to a Rerun viewer while it runs. A headless Rerun
gRPC server (`rerun --serve-grpc --save`) stands in for the viewer and keeps what arrives."""

import os
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from datasets.rerun_export import LIVE_RATE
from tests.datasets.conftest import RERUN

ROOT = Path(__file__).resolve().parents[2]
TESTBED = [sys.executable, "-m", "testbed.tools.cli"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def sink(tmp_path):
    """(URL, the .rrd it saves to) of a headless Rerun server on a free local port."""
    port, rrd = free_port(), tmp_path / "received.rrd"
    # Its own process group: the `rerun` command runs the viewer's binary as a child of its own.
    server = subprocess.Popen([str(RERUN), "--serve-grpc", "--port", str(port), "--save", str(rrd)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.1)
    yield f"rerun+http://127.0.0.1:{port}/proxy", rrd
    os.killpg(server.pid, signal.SIGINT)
    try:
        server.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(server.pid, signal.SIGKILL)


@pytest.mark.filterwarnings("ignore:RRD file has no footer")     # read while the server still writes it
def test_a_run_streams_the_robot_its_ghost_and_the_plots_while_it_runs(sink, tmp_path):
    url, rrd = sink
    done = subprocess.run([*TESTBED, "run", "--terrain", "flat", "--gait", "tripod", "--estimator", "ekf",
                           "--duration", "2", "--no-record", "--rerun-live", "--rerun-connect", url],
                          cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = Counter()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and rows["/transforms/body"] < 2 * LIVE_RATE:
        time.sleep(0.5)
        rows = Counter()
        for chunk in RrdReader(rrd).stream().to_chunks():
            if not chunk.is_static:
                rows[chunk.entity_path] += chunk.num_rows
    expected = int(2 * LIVE_RATE) + 1          # a row every 1 / LIVE_RATE s of simulated time, t = 0 included
    assert rows["/transforms/body"] == expected
    assert rows["/transforms/estimate/body"] == rows["/transforms/body"]
    assert rows["/transforms/joints"] == 18 * rows["/transforms/body"]
    assert rows["/plots/attitude/roll/truth"] == rows["/transforms/body"]
    assert 0 < rows["/plots/attitude/pitch/estimate"] <= rows["/transforms/body"]


@pytest.mark.parametrize("arguments, message", [
    (["--rerun-connect", "rerun+http://127.0.0.1:9/proxy"], "--rerun-live"),
    (["--rerun-live", "--rerun-connect", "http://127.0.0.1:9876"], "rerun+http"),
    (["--rerun-live"], "no display"),
])
def test_live_options_are_checked_before_the_run(tmp_path, arguments, message):
    env = {key: value for key, value in ENV.items() if key not in ("DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run([*TESTBED, "run", "--no-record", *arguments], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1 and message in done.stderr
    assert list(tmp_path.iterdir()) == []
