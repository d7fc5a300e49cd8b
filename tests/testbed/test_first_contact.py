"""What a new user meets first: a progress bar on a terminal and silence when piped, runs without a
recording, a command line that answers bad input without loading the simulation, and a sweep that walks."""

import json
import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
TESTBED = [sys.executable, "-m", "testbed.tools.cli"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
BAR = re.compile(r"\d+%\|")
# Colour attributes draw nothing: colorama (when installed) resets them at exit, after numba used it for a message.
ANSI_ATTRIBUTES = re.compile(r"\x1b\[[0-9;]*m")
HEAVY = ("dartpy", "numba", "scipy", "mcap", "rerun")


def under_terminal(argv: list[str], cwd: Path, timeout: float = 300.0) -> tuple[int, str]:
    """Run `argv` with a pseudo-terminal as its stdin, stdout and stderr; its exit code and output."""
    controller, terminal = pty.openpty()
    process = subprocess.Popen(argv, stdin=terminal, stdout=terminal, stderr=terminal, cwd=cwd, env=ENV,
                               close_fds=True)
    os.close(terminal)
    output, deadline = b"", time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([controller], [], [], 0.5)
            if ready:
                try:
                    chunk = os.read(controller, 65536)
                except OSError:         # the terminal closed: the process ended
                    break
                if not chunk:
                    break
                output += chunk
            elif process.poll() is not None:
                break
    finally:
        os.close(controller)
    return process.wait(timeout=10), ANSI_ATTRIBUTES.sub("", output.decode(errors="replace"))


def test_run_shows_a_bar_in_simulated_seconds_on_a_terminal(tmp_path):
    code, output = under_terminal([*TESTBED, "run", "--terrain", "flat", "--duration", "1", "--no-record"], tmp_path)
    assert code == 0, output
    assert BAR.search(output) and "s simulated" in output and "real time" in output
    assert "1.0/1.0 s simulated" in output             # the bar ends at the simulated time reached
    assert not (tmp_path / "runs").exists()


def test_quiet_run_on_a_terminal_shows_no_bar(tmp_path):
    code, output = under_terminal([*TESTBED, "run", "--terrain", "flat", "--duration", "0.3", "--no-record",
                                   "--quiet"], tmp_path)
    assert code == 0, output
    assert not BAR.search(output)
    assert len(output.strip().splitlines()) == 1


@pytest.mark.parametrize("no_record", [["--no-record"], ["--out", "none"]])
def test_piped_run_prints_only_its_result_line_and_records_nothing(tmp_path, no_record):
    metrics = tmp_path / "m.json"
    done = subprocess.run([*TESTBED, "run", "--terrain", "flat", "--duration", "0.5", *no_record,
                           "--metrics", str(metrics)], cwd=tmp_path, env=ENV, capture_output=True, text=True)
    assert done.returncode == 0 and done.stderr == ""
    assert len(done.stdout.splitlines()) == 1 and "not recorded" in done.stdout
    assert sorted(path.name for path in tmp_path.iterdir()) == ["m.json"]
    data = json.loads(metrics.read_text())
    assert data["sim_steps"] == 500 and data["compile_s"] >= 0.0


def test_no_record_refuses_the_options_that_need_the_file(tmp_path):
    done = subprocess.run([*TESTBED, "run", "--no-record", "--rerun", "r.rrd"], cwd=tmp_path, env=ENV,
                          capture_output=True, text=True)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1 and "--no-record" in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_replay_shows_a_bar_on_a_terminal(tmp_path):
    run = tmp_path / "r.mcap"
    subprocess.run([*TESTBED, "run", "--terrain", "flat", "--duration", "1", "--out", str(run)], env=ENV,
                   check=True, capture_output=True)
    code, output = under_terminal([*TESTBED, "replay", str(run), "--estimator", "complementary"], tmp_path)
    assert code == 0, output
    assert BAR.search(output) and "replay" in output


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["run", "--terrain", "moon"],
                                  ["run", "--gait", "hop"], ["run", "--estimator", "kalmann"],
                                  ["run", "--duration", "soon"], ["rn"]])
def test_help_and_bad_names_answer_without_loading_the_simulation(argv):
    """The modules imported while answering: none of the simulation's (DART, numba, scipy) or the
    recording's, so that the answer comes in a fraction of a second."""
    probe = ("import sys\nfrom testbed.tools.cli import main\n"
             "try:\n    code = main(sys.argv[1:])\nexcept SystemExit as stop:\n    code = stop.code\n"
             f"print('\\nLOADED', sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})), code)")
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", probe, *argv], env=ENV, capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    loaded, code = done.stdout.rsplit("LOADED", 1)[1].split("]")
    assert loaded.strip() == "[", f"{argv} loaded {loaded}]"
    assert int(code) == (0 if "--help" in argv else 2)
    if int(code) == 2:
        assert len(done.stderr.splitlines()) == 1
    assert elapsed < 5.0          # a generous bound for a shared machine; about 0.1 s when idle


@pytest.mark.parametrize("gait, config, expected", [
    (None, None, "tripod"),            # as `testbed bench` walks
    ("ripple", None, "ripple"),
    (None, "[run]\ngait = \"ripple\"\n", None),     # the config file's gait stands
])
def test_sweep_walks_the_tripod_unless_told_otherwise(tmp_path, gait, config, expected):
    from argparse import Namespace

    from testbed.tools import sweep, sweep_cli

    path = None
    if config is not None:
        path = tmp_path / "c.toml"
        path.write_text(config)
    keys = sweep_cli._run_keys(Namespace(duration=2.0, gait=gait, config=path))
    assert keys.get("gait") == expected
    (spec,) = sweep.make_specs([sweep.GridPoint("flat", 0, "none", "default")], tmp_path,
                               sweep_cli._base(path), keys)
    assert spec.config["run"]["gait"] == (expected or "ripple")


def test_compilation_during_a_run_is_reported_apart_from_the_real_time_factor():
    """A kernel that numba compiles inside the run loop (not cached: this one is new to every
    process) is timed as compile_s and left out of wall_s, so realtime_factor is that of the
    simulation alone."""
    import numba

    import testbed
    from estimators import Estimator

    @numba.njit(cache=False)
    def scaled(values, factor):
        return values * factor

    class CompilesOnFirstSample(Estimator):
        def update(self, sample):
            scaled(np.zeros(3), 2.0)
            return None

    started = time.perf_counter()
    result = testbed.run({"run": {"terrain": "flat", "duration": 0.5}}, estimator=CompilesOnFirstSample())
    elapsed = time.perf_counter() - started
    m = result.metrics
    assert m["compile_s"] > 0.05
    assert m["realtime_factor"] == pytest.approx(m["sim_time_s"] / m["wall_s"])
    assert m["wall_s"] + m["compile_s"] < elapsed


def test_the_install_step_s_warm_up_says_what_it_does_and_shows_progress_on_a_terminal(tmp_path):
    code, output = under_terminal([sys.executable, "-m", "testbed.tools.warmup"], tmp_path)
    assert code == 0, output
    lines = output.strip().splitlines()
    assert lines[0].startswith("compiling kernels, first run only")
    assert BAR.search(output) and "kernels" in lines[-1]
    assert "Warning" not in output
