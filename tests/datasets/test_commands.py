"""`replay`, `info`, `view` and the recording options of `run`, through their argparse handlers."""

from __future__ import annotations

import argparse
import json

import pytest

from datasets import commands
from datasets.reader import read_recording
from estimators.scoring import METRIC_KEYS
from tests.datasets.conftest import run_rerun
from tests.datasets.ticks import synthetic_config
from testbed.tools.cli import OneLineParser
from testbed.model.errors import UserError


def parse(*argv: str) -> argparse.Namespace:
    parser = OneLineParser(prog="testbed")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    commands.add_subcommands(subparsers)
    run = subparsers.add_parser("run")
    commands.add_run_arguments(run)
    return parser.parse_args(list(argv))


def invoke(*argv: str) -> int:
    args = parse(*argv)
    return args.handler(args)


def test_replay_writes_the_metrics_and_a_new_dataset(ekf_run, tmp_path, capsys):
    _, _, path = ekf_run
    metrics, out = tmp_path / "m.json", tmp_path / "out.mcap"
    assert invoke("replay", str(path), "--estimator", "ekf", "--metrics", str(metrics), "--out", str(out)) == 0
    data = json.loads(metrics.read_text())
    assert set(METRIC_KEYS) <= set(data) and data["estimator"] == "ekf"
    assert read_recording(out).metrics()["roll_rmse_deg"] == data["roll_rmse_deg"]
    line = capsys.readouterr().out.strip()
    assert "through ekf" in line and "real time" in line and "\n" not in line


def test_replay_of_a_truncated_file_warns_in_one_line(ekf_run, tmp_path, capsys):
    _, _, path = ekf_run
    truncated = tmp_path / "t.mcap"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert invoke("replay", str(truncated), "--estimator", "ekf") == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("testbed: warning:") and "truncated" in err and "\n" not in err


def test_replay_refuses_to_overwrite_its_input_or_write_into_a_folder(ekf_run, tmp_path):
    _, _, path = ekf_run
    with pytest.raises(UserError, match="would overwrite"):
        invoke("replay", str(path), "--estimator", "ekf", "--out", str(path))
    with pytest.raises(UserError, match="is a directory"):
        invoke("replay", str(path), "--estimator", "ekf", "--metrics", str(tmp_path))


def test_replay_needs_an_estimator(ekf_run):
    _, _, path = ekf_run
    with pytest.raises(UserError, match="--estimator"):
        parse("replay", str(path))


def test_info_names_terrain_estimator_topics_and_metrics(ekf_run, capsys):
    _, _, path = ekf_run
    assert invoke("info", str(path)) == 0
    out = capsys.readouterr().out
    assert "terrain flat, estimator ekf" in out and "duration 2.000 s" in out and "(complete)" in out
    assert "/sensors/imu" in out and "1000.0 Hz" in out and "2001 msgs" in out
    assert "roll_rmse_deg: 0.5" in out


def test_info_of_a_truncated_file_says_so(ekf_run, tmp_path, capsys):
    _, _, path = ekf_run
    truncated = tmp_path / "t.mcap"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert invoke("info", str(truncated)) == 0
    out = capsys.readouterr().out
    assert "TRUNCATED" in out and "metrics: none" in out


def test_view_writes_a_verified_rrd(ekf_run, tmp_path):
    _, _, path = ekf_run
    rrd = tmp_path / "v.rrd"
    assert invoke("view", str(path), "--rrd", str(rrd)) == 0
    assert run_rerun("rrd", "verify", str(rrd)).returncode == 0


def test_spawn_without_a_display_says_so_and_goes_on(ekf_run, tmp_path, monkeypatch, capsys):
    _, _, path = ekf_run
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert invoke("view", str(path), "--rrd", str(tmp_path / "v.rrd"), "--spawn") == 0
    assert "no display" in capsys.readouterr().err


def test_run_records_to_out_or_to_a_default_path(tmp_path, monkeypatch):
    config = synthetic_config("ekf")
    assert commands.recorder_for(parse("run", "--out", str(tmp_path / "a.mcap")), config).path == tmp_path / "a.mcap"
    monkeypatch.chdir(tmp_path)
    default = commands.recorder_for(parse("run"), config).path
    assert default.parent.name == "runs" and default.name.endswith("_flat_ekf.mcap")
    with pytest.raises(UserError, match="--rerun .* is a directory"):
        commands.recorder_for(parse("run", "--rerun", str(tmp_path)), config)


def test_run_from_a_recording_gives_its_config(ekf_run):
    config, _, path = ekf_run
    assert commands.config_from_mcap(path) == json.loads(json.dumps(config.to_dict()))


def test_after_run_writes_the_rrd_only_when_asked(ekf_run, tmp_path):
    _, _, path = ekf_run
    commands.after_run(parse("run"), path)
    assert not path.with_suffix(".rrd").exists()
    rrd = tmp_path / "r.rrd"
    commands.after_run(parse("run", "--rerun", str(rrd)), path)
    assert rrd.exists()


def test_default_run_paths_never_collide_within_one_second(tmp_path):
    """Parallel runs started in the same second get different files (the .partial is reserved)."""
    from datasets.commands import default_run_path
    from testbed.runtime import config
    cfg = config.load()
    paths = [default_run_path(cfg, tmp_path) for _ in range(3)]
    assert len(set(paths)) == 3
    assert all(p.with_name(p.name + ".partial").exists() and not p.exists() for p in paths)
