"""`testbed sweep`: the grid, one complete MCAP and one index row per run, resume, retries after a
worker dies (local pool and a real Dask cluster), and bad input (exit 2, one line, nothing written).

Runs are short (0.5 s simulated) except where a worker must be killed in the middle of a run.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import psutil
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from testbed.tools import sweep
from testbed.tools.cli import main
from testbed.runtime.presets import preset_overrides

BIN = Path(sys.executable).parent
TESTBED = str(BIN / "testbed")
DASK = str(BIN / "dask")
ESTIMATOR = "complementary"    # cheap and stable: these tests are about the sweep, not the estimators
GRID = ["--terrains", "flat,step", "--seeds", "2", "--estimators", ESTIMATOR]
NAMES = {f"{terrain}_seed{seed:03d}_{ESTIMATOR}_default" for terrain in ("flat", "step") for seed in (0, 1)}
KILL_DURATION = "5.0"       # s simulated: a second or two of wall time each, so that two runs overlap long enough to be killed in
ONE_THREAD = {name: "1" for name in sweep.THREAD_VARIABLES}


def mcaps(folder: Path) -> set[str]:
    return {path.name.removesuffix(".mcap") for path in folder.glob("*.mcap")}


def partials(folder: Path) -> set[str]:
    return {path.name.removesuffix(".mcap.partial") for path in folder.glob("*.mcap.partial")}


def index_rows(folder: Path) -> dict[str, dict]:
    return {row["name"]: row for row in pq.read_table(folder / sweep.INDEX_FILE).to_pylist()}


def mtimes(folder: Path) -> dict[str, int]:
    return {path.name: path.stat().st_mtime_ns for path in folder.glob("*.mcap")}


def run_now(stdout: str) -> int:
    return int(re.search(r"\((\d+) run now", stdout).group(1))


def recorded(path: Path) -> tuple[dict, dict]:
    """(config, metrics) of a complete MCAP; fails on a file without its summary."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_summary() is not None, f"{path.name} is not a complete MCAP"
        metadata = {record.name: record.metadata for record in reader.iter_metadata()}
    return json.loads(metadata["config"]["json"]), json.loads(metadata["metrics"]["json"])


def wait_for(condition, timeout: float, what: str, process: subprocess.Popen | None = None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if process is not None and process.poll() is not None:
            pytest.fail(f"{what}: the process ended first with code {process.returncode}")
        time.sleep(0.02)
    pytest.fail(f"timed out waiting for {what}")


def scheduler_address(scheduler_file: Path) -> str | None:
    """The address in a dask scheduler file, or None until the scheduler has written all of it
    (the file appears before its contents)."""
    try:
        return json.loads(scheduler_file.read_text())["address"]
    except (FileNotFoundError, json.JSONDecodeError, KeyError):
        return None


def stop(processes: list[subprocess.Popen]) -> None:
    for process in processes:
        if process.poll() is None:
            process.terminate()
    for process in processes:
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    """A finished 4-run sweep on 2 local workers (tests copy it before changing anything)."""
    folder = tmp_path_factory.mktemp("sweep") / "runs"
    assert main(["sweep", *GRID, "--duration", "0.5", "--workers", "2", "--out", str(folder)]) == 0
    return folder


def copy_of(swept: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "runs"
    shutil.copytree(swept, folder)       # copy2 keeps the modification times
    return folder


# --- the grid --------------------------------------------------------------------------------

def test_grid_is_every_combination_with_deterministic_names():
    points = sweep.expand_grid(["flat", "step"], range(3), ["ekf", "vqf"], ["default", "consumer"])
    assert len(points) == 2 * 3 * 2 * 2 == len({point.name for point in points})
    assert points[0].name == "flat_seed000_ekf_default" and points[-1].name == "step_seed002_vqf_consumer"
    assert [point.seed for point in points[:4]] == [0, 0, 0, 0] and points[4].seed == 1


def test_each_run_config_carries_its_grid_point_and_preset(tmp_path):
    points = sweep.expand_grid(["step"], [7], ["vqf"], ["consumer"])
    (spec,) = sweep.make_specs(points, tmp_path, base={"gait": {"speed": 0.05}}, run={"duration": 3.0})
    run = spec.config["run"]
    assert (run["terrain"], run["seed"], run["estimator"], run["duration"]) == ("step", 7, "vqf", 3.0)
    consumer = preset_overrides("consumer")["sensors"]["imu"]["accel"]["noise_density"]
    assert spec.config["sensors"]["imu"]["accel"]["noise_density"] == consumer
    assert spec.config["gait"]["speed"] == 0.05
    assert spec.path == str(tmp_path / "step_seed007_vqf_consumer.mcap")
    other = sweep.make_specs(sweep.expand_grid(["step"], [8], ["vqf"], ["consumer"]), tmp_path)[0]
    assert other.config_hash != spec.config_hash


# --- a sweep and its index -------------------------------------------------------------------

def test_sweep_writes_one_complete_mcap_and_one_index_row_per_run(swept):
    assert mcaps(swept) == NAMES and not partials(swept)
    rows = index_rows(swept)
    assert set(rows) == NAMES
    for name, row in rows.items():
        config, metrics = recorded(swept / f"{name}.mcap")
        assert config["run"]["seed"] == row["seed"] == int(name.split("seed")[1][:3])
        assert config["run"]["terrain"] == row["terrain"] == name.split("_")[0]
        assert config["run"]["duration"] == row["duration_s"] == 0.5
        assert row["sim_steps"] == metrics["sim_steps"] == 500
        assert row["roll_rmse_deg"] == pytest.approx(metrics["roll_rmse_deg"])
        assert row["error"] == "" and row["fell"] is False
        assert row["elapsed_s"] >= row["wall_s"] > 0 and row["cpu_s"] > 0    # the run loop is part of the run
    csv = pa_csv.read_csv(swept / sweep.INDEX_CSV).to_pylist()
    assert sorted(row["name"] for row in csv) == sorted(NAMES)


def test_resume_runs_only_what_is_not_done(swept, tmp_path, capsys):
    folder = copy_of(swept, tmp_path)
    before = mtimes(folder)
    assert main(["sweep", *GRID, "--duration", "0.5", "--workers", "2", "--out", str(folder)]) == 0
    assert "done already" in capsys.readouterr().out and mtimes(folder) == before

    (folder / f"step_seed001_{ESTIMATOR}_default.mcap").unlink()        # a lost file
    index = sweep.Index.load(folder)
    del index.rows[f"flat_seed000_{ESTIMATOR}_default"]                   # a row never written
    index.save()
    assert main(["sweep", *GRID, "--duration", "0.5", "--workers", "2", "--out", str(folder)]) == 0
    assert run_now(capsys.readouterr().out) == 2
    after = mtimes(folder)
    for kept in (f"flat_seed001_{ESTIMATOR}_default.mcap", f"step_seed000_{ESTIMATOR}_default.mcap"):
        assert after[kept] == before[kept]
    assert after[f"flat_seed000_{ESTIMATOR}_default.mcap"] > before[f"flat_seed000_{ESTIMATOR}_default.mcap"]
    assert set(index_rows(folder)) == NAMES


def test_a_grown_grid_runs_the_new_points_and_keeps_the_old_rows(swept, tmp_path, capsys):
    folder = copy_of(swept, tmp_path)
    assert main(["sweep", "--terrains", "flat", "--seeds", "1", "--estimators", ESTIMATOR, "--sensors",
                 "default,tactical", "--duration", "0.5", "--workers", "1", "--out", str(folder)]) == 0
    assert run_now(capsys.readouterr().out) == 1
    rows = index_rows(folder)
    new = f"flat_seed000_{ESTIMATOR}_tactical"
    assert set(rows) == NAMES | {new} and rows[new]["sensors"] == "tactical"
    config, _ = recorded(folder / f"{new}.mcap")
    assert config["sensors"]["imu"]["gyro"]["bits"] == 32


def test_another_config_in_the_same_folder_is_refused_untouched(swept, tmp_path, capsys):
    folder = copy_of(swept, tmp_path)
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    assert main(["sweep", *GRID, "--duration", "1", "--workers", "2", "--out", str(folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert "run.duration 0.5 there, 1.0 here" in err and "\n" not in err
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before


def test_a_damaged_index_is_refused_untouched(swept, tmp_path, capsys):
    folder = copy_of(swept, tmp_path)
    (folder / sweep.INDEX_FILE).write_bytes(b"not parquet")
    before = mtimes(folder)
    assert main(["sweep", *GRID, "--duration", "0.5", "--workers", "2", "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "cannot read the sweep index" in err and err.count("\n") == 1
    assert (folder / sweep.INDEX_FILE).read_bytes() == b"not parquet" and mtimes(folder) == before


def test_interrupted_sweep_keeps_finished_runs_and_resumes(tmp_path, capsys):
    folder = tmp_path / "runs"
    arguments = ["sweep", "--terrains", "flat", "--seeds", "3", "--estimators", ESTIMATOR, "--duration", "0.5",
                 "--workers", "1", "--out", str(folder)]
    process = subprocess.Popen([TESTBED, *arguments], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (folder / sweep.INDEX_FILE).exists(), 120, "the first finished run", process)
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        stop([process])
    assert process.returncode == 130 and "run the same command again to resume" in err
    assert "Traceback" not in err
    finished = set(index_rows(folder))
    assert 1 <= len(finished) < 3 and finished <= mcaps(folder)

    assert main(arguments) == 0
    assert run_now(capsys.readouterr().out) == 3 - len(finished)
    assert len(index_rows(folder)) == 3 and len(mcaps(folder)) == 3 and not partials(folder)


def test_a_killed_local_worker_does_not_lose_runs(tmp_path):
    folder = tmp_path / "runs"
    process = subprocess.Popen([TESTBED, "sweep", *GRID, "--duration", KILL_DURATION, "--workers", "2",
                                "--out", str(folder)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        in_flight = wait_for(lambda: partials(folder) if len(partials(folder)) == 2 else None, 120,
                             "two runs in flight", process)
        workers = [child for child in psutil.Process(process.pid).children()
                   if "spawn_main" in " ".join(child.cmdline())]
        assert len(workers) == 2
        workers[0].kill()
        out, err = process.communicate(timeout=300)
    finally:
        stop([process])
    assert process.returncode == 0, err
    assert int(re.search(r"(\d+) retried", out).group(1)) >= 1 and "its worker died" in err
    rows = index_rows(folder)
    assert set(rows) == NAMES == mcaps(folder) and not partials(folder)
    for name in in_flight:
        recorded(folder / f"{name}.mcap")


# --- a real Dask cluster ---------------------------------------------------------------------

@pytest.fixture
def cluster(tmp_path):
    """A `dask scheduler` and two single-thread `dask worker` processes (no nanny: a killed worker
    stays dead) on 127.0.0.1; yields (address, {worker pid: Popen})."""
    with dask_cluster(tmp_path, {**os.environ, **ONE_THREAD}) as running:
        yield running


@contextmanager
def dask_cluster(tmp_path, environment: dict):
    from distributed import Client

    processes: list[subprocess.Popen] = []
    logs = tmp_path / "cluster-logs"
    logs.mkdir()

    def start(name: str, *arguments: str) -> subprocess.Popen:
        log = (logs / f"{name}.log").open("w")
        process = subprocess.Popen([DASK, *arguments], stdout=log, stderr=subprocess.STDOUT, env=environment,
                                   cwd=logs)
        processes.append(process)
        return process

    try:
        scheduler_file = logs / "scheduler.json"
        start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(scheduler_file))
        address = wait_for(lambda: scheduler_address(scheduler_file), 60, "the dask scheduler", processes[0])
        workers = [start(f"worker{i}", "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                         "--host", "127.0.0.1", "--name", f"w{i}") for i in range(2)]
        with Client(address, timeout=30, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=60)
        yield address, {worker.pid: worker for worker in workers}
    finally:
        stop(processes[1:])          # the workers first: without a scheduler they try to reconnect
        stop(processes[:1])


def test_dask_sweep_survives_a_killed_worker(cluster, tmp_path):
    address, workers = cluster
    folder = tmp_path / "runs"
    process = subprocess.Popen([TESTBED, "sweep", *GRID, "--duration", KILL_DURATION, "--scheduler", address,
                                "--out", str(folder)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=tmp_path)
    try:
        in_flight = wait_for(lambda: partials(folder) if len(partials(folder)) == 2 else None, 120,
                             "two runs in flight", process)
        killed, survivor = list(workers)
        workers[killed].kill()
        out, err = process.communicate(timeout=300)
    finally:
        stop([process])
    assert process.returncode == 0, err
    rows = index_rows(folder)
    assert set(rows) == NAMES == mcaps(folder) and not partials(folder)
    pids = {name: int(row["worker"].rsplit(":", 1)[1]) for name, row in rows.items()}
    assert set(pids.values()) <= set(workers)
    # Both runs in flight at the kill were finished by the surviving worker: the killed one was redone.
    assert {pids[name] for name in in_flight} == {survivor}
    for name in rows:
        recorded(folder / f"{name}.mcap")


def test_dask_workers_import_a_plugin_estimator_and_terrain_themselves(tmp_path):
    examples = str(Path(__file__).resolve().parents[2] / "examples")
    plugin_env = {**os.environ, **ONE_THREAD, "PYTHONPATH": examples}
    with dask_cluster(tmp_path, plugin_env) as (address, _):
        result = subprocess.run([TESTBED, "sweep", "--terrains", "flat,my_terrain:Washboard", "--estimators",
                                 "my_estimator:MyComplementary", "--seeds", "1", "--duration", "1.5", "--gait", "tripod",
                                 "--scheduler", address, "--out", str(tmp_path / "runs")],
                                capture_output=True, text=True, timeout=600, cwd=tmp_path, env=plugin_env)
    assert result.returncode == 0, result.stderr
    rows = index_rows(tmp_path / "runs")
    assert {row["terrain"] for row in rows.values()} == {"flat", "my_terrain:Washboard"}
    assert {row["estimator"] for row in rows.values()} == {"my_estimator:MyComplementary"}


# --- bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize("arguments", [
    ["--terrains", "moon"],
    ["--terrains", "flat,,step"],
    ["--estimators", "kalman"],
    ["--sensors", "military"],
    ["--seeds", "0"],
    ["--seeds", "two"],
    ["--first-seed", "-1"],
    ["--workers", "0"],
    ["--duration", "0"],
    ["--gait", "hop"],
    ["--max-attempts", "0"],
    ["--config", "/nonexistent.toml"],
    ["--scheduler", "127.0.0.1:8786"],
    ["--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"],
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(arguments, tmp_path, capsys):
    folder = tmp_path / "runs"
    assert main(["sweep", *arguments, "--out", str(folder)]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("testbed") and captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert not folder.exists() and captured.out == ""


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    out = tmp_path / "runs"
    out.write_text("keep me")
    assert main(["sweep", "--out", str(out)]) == 2
    assert "is a file" in capsys.readouterr().err and out.read_text() == "keep me"


def test_unreachable_scheduler_fails_quickly(tmp_path, capsys):
    with socket.socket() as probe:      # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    folder = tmp_path / "runs"
    started = time.monotonic()
    assert main(["sweep", "--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout", "1",
                 "--out", str(folder)]) == 2
    assert time.monotonic() - started < 10
    err = capsys.readouterr().err
    assert "cannot reach the Dask scheduler" in err and err.count("\n") == 1
    assert not folder.exists()
