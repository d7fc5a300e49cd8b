"""The plugins of examples/ run as a new user would run them (docs/extending.md): from the command
line with PYTHONPATH=examples, through run, replay, run --from, bench and sweep."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TESTBED = [sys.executable, "-m", "testbed.tools.cli"]
ESTIMATOR = "my_estimator:MyComplementary"


def run_cli(arguments: list[str], cwd: Path) -> subprocess.CompletedProcess:
    # the project's own root too: the commands run the code under test, not an installed copy
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(EXAMPLES), str(EXAMPLES.parent)]))
    result = subprocess.run(TESTBED + arguments, capture_output=True, text=True, timeout=600, env=env, cwd=cwd)
    assert result.returncode == 0, result.stderr
    return result


def metrics(path: Path) -> dict:
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def estimator_run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("estimator")
    run_cli(["run", "--estimator", ESTIMATOR, "--gait", "tripod", "--duration", "4", "--out", "e.mcap",
             "--metrics", "e.json"], folder)
    return folder


def test_the_estimator_plugin_runs_live_and_is_scored(estimator_run):
    m = metrics(estimator_run / "e.json")
    assert m["fell"] is False
    assert 0 < m["roll_rmse_deg"] < 1.0 and 0 < m["pitch_rmse_deg"] < 2.0


def test_replay_through_the_plugin_reproduces_the_live_estimates(estimator_run):
    run_cli(["replay", "e.mcap", "--estimator", ESTIMATOR, "--metrics", "r.json"], estimator_run)
    live, replayed = metrics(estimator_run / "e.json"), metrics(estimator_run / "r.json")
    assert replayed["roll_rmse_deg"] == live["roll_rmse_deg"]
    assert replayed["pitch_rmse_deg"] == live["pitch_rmse_deg"]


def test_run_from_a_plugin_run_repeats_it(estimator_run):
    run_cli(["run", "--from", "e.mcap", "--out", "again.mcap", "--metrics", "again.json"], estimator_run)
    first, again = metrics(estimator_run / "e.json"), metrics(estimator_run / "again.json")
    for key in ("roll_rmse_deg", "pitch_rmse_deg", "distance_m", "tilt_rms_deg"):
        assert again[key] == first[key]


def test_the_controller_plugin_stands_and_sways_level(tmp_path):
    run_cli(["run", "--controller", "my_controller:BodySway", "--estimator", "ekf", "--duration", "6",
             "--out", "c.mcap", "--metrics", "c.json"], tmp_path)
    m = metrics(tmp_path / "c.json")
    assert m["fell"] is False and m["tilt_max_deg"] < 2.0
    assert 0.01 < m["distance_m"] < 0.06         # the body moved with the sway, the feet stayed


def test_the_terrain_plugin_is_walked_with_the_posture_controller(tmp_path):
    run_cli(["run", "--terrain", "my_terrain:Washboard", "--gait", "tripod", "--controller", "posture",
             "--estimator", "ekf", "--duration", "8", "--out", "t.mcap", "--metrics", "t.json"], tmp_path)
    m = metrics(tmp_path / "t.json")
    assert m["fell"] is False and m["distance_m"] > 0.3 and m["tilt_max_deg"] < 2.0


@pytest.mark.parametrize("terrain", ["step", "slope"])
def test_the_posture_law_plugin_levels_the_body_with_the_built_in_gait(terrain, tmp_path):
    run_cli(["run", "--terrain", terrain, "--gait", "tripod", "--controller", "posture", "--estimator", "ekf",
             "--set", "posture.law=my_posture_law:IntegralLevelling", "--duration", "8", "--seed", "7",
             "--out", "p.mcap", "--metrics", "p.json"], tmp_path)
    m = metrics(tmp_path / "p.json")
    assert m["fell"] is False and m["tilt_rms_deg"] < 0.3 and m["tilt_max_deg"] < 1.0 and m["ik_limited_ticks"] == 0


def test_bench_compares_the_plugin_with_a_built_in(tmp_path):
    run_cli(["bench", "--terrains", "flat", "--seeds", "1", "--duration", "3", "--estimators", f"ekf,{ESTIMATOR}",
             "--workers", "1", "--out", "bench", "--cache", "cache"], tmp_path)
    rows = json.loads((tmp_path / "bench" / "results.json").read_text())
    assert ESTIMATOR in json.dumps(rows) and ESTIMATOR in (tmp_path / "bench" / "results.md").read_text()


def test_sweep_runs_the_plugins_on_two_workers(tmp_path):
    run_cli(["sweep", "--terrains", "flat,my_terrain:Washboard", "--estimators", ESTIMATOR, "--seeds", "1",
             "--duration", "2", "--gait", "tripod", "--workers", "2", "--out", "sweep"], tmp_path)
    index = pd.read_csv(tmp_path / "sweep" / "index.csv")
    assert len(index) == 2 and set(index["estimator"]) == {ESTIMATOR}
    assert sorted(index["terrain"]) == ["flat", "my_terrain:Washboard"]
