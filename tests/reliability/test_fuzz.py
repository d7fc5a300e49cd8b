"""Fuzzing the command line in process (`testbed.tools.cli.main`, stderr captured): random
arguments, TOML files and corrupted MCAP files never give a traceback, a hang or a wrong exit code.
The count of cases tried is printed at the end of the session (conftest.py).
A simulation that the arguments would start is replaced by a stand-in that stops at once (the
arguments were accepted), so that thousands of cases run in seconds. Each test prints its count."""

from __future__ import annotations

import io
import signal
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from datasets.recorder import McapRecorder
from testbed.runtime import runner
from testbed.tools import cli
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf

HANG_S = 60
FUZZ = settings(deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
counts: dict[str, int] = {}


class Accepted(BaseException):
    """Raised in place of the simulation: the command line accepted the input."""


@contextmanager
def alarm(seconds: int):
    def hang(signum, frame):
        raise AssertionError(f"no answer in {seconds} s")
    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def call(kind: str, argv: list[str], allowed=(0, 1, 2)) -> tuple[int | None, str]:
    """Exit code (None when a run was accepted) and stderr of `testbed ARGV`; fails on a traceback,
    an unexpected exception, a second line on stderr or an exit code out of `allowed`."""
    counts[kind] = counts.get(kind, 0) + 1
    err, out = io.StringIO(), io.StringIO()
    try:
        with alarm(HANG_S), redirect_stderr(err), redirect_stdout(out):
            status = cli.main(argv)
    except Accepted:
        status = None
    text = err.getvalue()
    assert "Traceback" not in text, (argv, text)
    assert "testbed: failed:" not in text, (argv, text)         # the catch-all: an unforeseen exception
    lines = [line for line in text.splitlines() if not line.startswith("testbed: warning:")]
    assert len(lines) <= 1, (argv, text)
    assert status is None or status in allowed, (argv, status, text)
    if status == 2:
        assert len(lines) == 1, (argv, text)
    return status, text


@pytest.fixture(autouse=True)
def no_simulation(monkeypatch):
    def accepted(*args, **kwargs):
        raise Accepted
    monkeypatch.setattr(runner, "build_parts", accepted)
    monkeypatch.setattr(runner, "run", accepted)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    config = synthetic_config("complementary")
    path = tmp_path_factory.mktemp("fuzz") / "run.mcap"
    recorder = McapRecorder(path, flush_period=0.25)
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    for tick in generate_ticks(config, 1.5):
        recorder.record(tick)
    recorder.finish({"roll_rmse_deg": 0.5}, None)
    return path


SUBCOMMANDS = ["run", "export-urdf", "info", "replay", "view", "sweep", "profile", "bench", "nope", ""]
OPTIONS = ["--terrain", "--contact", "--gait", "--speed", "--lateral-speed", "--turn-rate", "--target", "--estimator",
           "--controller", "--fault", "--duration", "--seed", "--config", "--set", "--metrics", "--out", "--rerun",
           "--from", "--force", "--rrd", "--json", "--seeds", "--scheduler", "--workers", "--connect-timeout"]
VALUES = ["flat", "step", "rough", "slope", "tripod", "ekf", "none", "posture", "dart", "1", "-1", "0", "1e308", "nan",
          "inf", "1e-9", "²", "١", "leg²", "1,2", "1e9,0", "nan,0", "run=5", "run.duration=0.5", "robot.tibia_length=1e9",
          "run.time_step=1e-9", "encoder.leg2.dropout@1s", "imu.accel.spike@5s", "x\ny", "a" * 300, "/dev/zero",
          "/", "/nonexistent/dir/f", "tcp://127.0.0.1:²", "[[[[", "{a=1}", "os:system", "9" * 40]
TOKEN = st.one_of(st.sampled_from(OPTIONS), st.sampled_from(VALUES),
                  st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12))


@FUZZ
@given(st.sampled_from(["run", "export-urdf", "nope"]), st.lists(TOKEN, max_size=8))
def test_random_arguments(tmp_path_factory, subcommand, tokens):
    folder = tmp_path_factory.mktemp("args")
    argv = [subcommand, *tokens]
    if subcommand == "export-urdf":
        argv = [subcommand, str(folder / "r.urdf"), *tokens]
    call("arguments", argv)


@FUZZ
@given(st.lists(st.sampled_from(VALUES), min_size=1, max_size=3), st.sampled_from(["--set", "--fault", "--target"]))
def test_named_values(values, option):
    call("named values", ["run", *[item for value in values for item in (option, value)]])


TOML_KEYS = st.sampled_from(["run", "duration", "time_step", "seed", "terrain", "gait", "robot", "tibia_length",
                             "sensors", "faults", "gait", "target", "x", "é", ""])
TOML_VALUES = st.recursive(
    st.one_of(st.integers(), st.floats(allow_nan=True), st.booleans(), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(TOML_KEYS, inner, max_size=3)), max_leaves=8)


def as_toml(table: dict) -> str:
    import tomli_w
    return tomli_w.dumps(table)


@FUZZ
@given(st.dictionaries(TOML_KEYS, TOML_VALUES, max_size=4))
def test_random_toml_tables(tmp_path_factory, table):
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    try:
        path.write_text(as_toml(table))
    except (TypeError, ValueError):
        return
    call("toml tables", ["run", "--config", str(path)])


@FUZZ
@given(st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_random_toml_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_bytes(data)
    call("toml bytes", ["run", "--config", str(path)])


def mutated(data: bytes, flips: list[tuple[int, int]], cut: int | None) -> bytes:
    data = bytearray(data)
    for position, value in flips:
        data[position % len(data)] = value
    return bytes(data[:cut] if cut is not None else data)


MUTATIONS = (st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 255)), max_size=6),
             st.none() | st.integers(0, 2**20))


@FUZZ
@given(*MUTATIONS)
def test_corrupted_files_through_info(recorded, tmp_path_factory, flips, cut):
    path = tmp_path_factory.mktemp("mcap") / "bad.mcap"
    path.write_bytes(mutated(recorded.read_bytes(), flips, cut))
    call("mcap info", ["info", str(path)])
    call("mcap run --from", ["run", "--from", str(path)])


@settings(FUZZ, max_examples=25)
@given(*MUTATIONS)
def test_corrupted_files_through_replay_and_view(recorded, tmp_path_factory, flips, cut):
    folder = tmp_path_factory.mktemp("mcap")
    path = folder / "bad.mcap"
    path.write_bytes(mutated(recorded.read_bytes(), flips, cut))
    call("mcap replay", ["replay", str(path), "--estimator", "complementary"])
    call("mcap view", ["view", str(path), "--rrd", str(folder / "bad.rrd")])


@pytest.mark.parametrize("argv", [
    ["run", "--set", "run.duration=" + "[" * 5000 + "]" * 5000],
    ["run", "--fault", "encoder.leg².dropout@1s"],
    ["info", "{garbage}"],
    ["replay", "{garbage}", "--estimator", "ekf"],
])
def test_a_few_cases_in_a_process_of_their_own(tmp_path, argv):
    from tests.reliability.cli_process import finish, start

    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)
    counts["subprocess"] = counts.get("subprocess", 0) + 1
    status, _, err = finish(start(*[arg.format(garbage=garbage) for arg in argv]), timeout=HANG_S)
    assert status == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
