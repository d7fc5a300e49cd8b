"""Every named bad input of issue 19: one line on stderr, exit 2 (1 for a failure during the work),
nothing written, nothing lost."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from datasets import schemas
from tests.reliability import damaged
from tests.reliability.cli_process import ROOT, run_main


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    return damaged.record_run(tmp_path_factory.mktemp("recorded") / "run.mcap")


def refused(argv, folder: Path | None = None, status: int = 2, says: str = "") -> str:
    before = set(folder.rglob("*")) if folder is not None else set()
    code, _, err = run_main(argv)
    assert code == status, (argv, code, err)
    assert says in err, err
    if folder is not None:
        assert set(folder.rglob("*")) == before, "something was written"
    return err


DEEP = "[" * 20000 + "]" * 20000


@pytest.mark.parametrize("argv,says", [
    (["run", "--set", f"run.duration={DEEP}"], "nested"),
    (["run", "--duration", "1", "--fault", "encoder.leg².dropout@1s"], "unknown leg"),
    (["run", "--fault", "accel_array.².spike@1s"], "member index"),
    (["run", "--set", "run=5", "--duration", "1"], "section"),
    (["run", "--set", "run=5"], "must be a table"),
    (["run", "--target", "1e308,1e308"], "within 1000 m"),
    (["run", "--target", "1e9,0"], "within 1000 m"),
    (["run", "--set", "run.time_step=1e-9"], "physics steps"),
    (["run", "--set", "gait.end_at_arrival=true"], "needs a gait.target"),
    (["run", "--set", "robot.tibia_length=1e9", "--duration", "0.1"], "start pose"),
    (["run", "--config", "/dev/zero"], "not a regular file"),
    (["sweep", "--seeds", "1000000000", "--out", "{tmp}/sweep"], "--seeds"),
    (["sweep", "--scheduler", "tcp://127.0.0.1:²", "--out", "{tmp}/sweep"], "--scheduler"),
    (["replay", "{recorded}", "--estimator", "none"], "nothing to replay"),
])
def test_named_bad_arguments(tmp_path, recorded, argv, says):
    argv = [arg.format(tmp=tmp_path, recorded=recorded) for arg in argv]
    refused(argv + (["--out", str(tmp_path / "x.mcap")] if argv[0] == "run" else []), tmp_path, says=says)


def test_a_deeply_nested_config_file(tmp_path):
    config = tmp_path / "deep.toml"
    config.write_text(f"[run]\nduration = {DEEP}\n")
    refused(["run", "--config", config, "--out", tmp_path / "x.mcap"], says="nested")


def test_a_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    refused(["run", "--config", fifo], says="not a regular file")
    refused(["info", fifo], says="not a regular file")


def test_names_with_newlines_stay_on_one_line(tmp_path):
    err = refused(["run", "--estimator", "e\nkf", "--out", tmp_path / "x.mcap"])
    assert "e\\nkf" in err
    err = refused(["export-urdf", tmp_path / "a\nb" / "c.urdf", "--config", tmp_path / "no\nfile.toml"])
    assert "\\n" in err


# --- the output rule -------------------------------------------------------------------------

OUTPUTS = [
    ["run", "--duration", "0.1", "--metrics", "{target}", "--out", "{tmp}/r.mcap"],
    ["run", "--duration", "0.1", "--rerun", "{target}", "--out", "{tmp}/r.mcap"],
    ["run", "--duration", "0.1", "--out", "{target}"],
    ["replay", "{recorded}", "--estimator", "complementary", "--out", "{target}"],
    ["replay", "{recorded}", "--estimator", "complementary", "--metrics", "{target}"],
    ["view", "{recorded}", "--rrd", "{target}"],
    ["export-urdf", "{target}"],
    ["profile", "--duration", "0.1", "--json", "{target}"],
    ["bench", "--out", "{target}"],
    ["bench", "--out", "{tmp}/bench", "--cache", "{target}"],
]


@pytest.mark.parametrize("argv", OUTPUTS, ids=lambda argv: f"{argv[0]} {[a for a in argv if '{target}' in a]}")
def test_an_output_under_a_file_is_refused(tmp_path, recorded, argv):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    target = blocker / "sub" / "out.x"
    refused([arg.format(tmp=tmp_path, recorded=recorded, target=target) for arg in argv], tmp_path)


@pytest.mark.parametrize("argv", [argv for argv in OUTPUTS if argv[0] not in ("bench",)])
def test_an_existing_output_is_replaced_only_with_force(tmp_path, recorded, argv):
    target = tmp_path / "existing.out"
    target.write_text("keep me")
    refused([arg.format(tmp=tmp_path, recorded=recorded, target=target) for arg in argv], tmp_path, says="--force")
    assert target.read_text() == "keep me"


def test_missing_parent_folders_are_created(tmp_path):
    target = tmp_path / "new" / "deeper" / "robot.urdf"
    assert run_main(["export-urdf", target])[0] == 0
    assert target.read_text().startswith("<?xml") or "<robot" in target.read_text()
    assert run_main(["export-urdf", target, "--force"])[0] == 0


# --- damaged and foreign files ---------------------------------------------------------------

def test_recorded_json_nested_deep_or_of_the_wrong_type(tmp_path):
    for name, text in (("deep", DEEP), ("list", "[1, 2]"), ("bits", '{"run": {"duratiom": 1}}')):
        path = damaged.written(tmp_path / f"{name}.mcap", config_json=text)
        refused(["info", path], says="config")
        refused(["replay", path, "--estimator", "ekf"])
        refused(["run", "--from", path, "--out", tmp_path / "x.mcap"])


def test_recorded_metrics_of_the_wrong_type(tmp_path):
    path = damaged.written(tmp_path / "metrics.mcap", metrics_json="[1, 2, 3]")
    refused(["info", path], says="metrics")


def test_a_file_cut_before_its_config(tmp_path, recorded):
    path = tmp_path / "cut.mcap"
    path.write_bytes(damaged.cut_before_config(recorded.read_bytes()))
    refused(["info", path], says="no testbed run config")


def test_garbage_payloads_and_arrays_of_the_wrong_length(tmp_path, recorded):
    messages = damaged.topics_of(recorded)
    garbage = [(topic, ns, b"\xff\x01garbage" if topic == schemas.TRUTH_POSE.name else data)
               for topic, ns, data in messages]
    path = damaged.written(tmp_path / "garbage.mcap", messages=garbage)
    refused(["replay", path, "--estimator", "complementary"], says="damaged or foreign")
    refused(["view", path, "--rrd", tmp_path / "g.rrd"], says="damaged or foreign")
    from datasets.codec import Encoder
    short = [(topic, ns, data[: len(data) // 2] if topic == schemas.TRUTH_FEET.name else data)
             for topic, ns, data in messages]
    path = damaged.written(tmp_path / "short.mcap", messages=short)
    code, _, err = run_main(["replay", path, "--estimator", "complementary"])
    assert code == 2 and "damaged or foreign" in err


@pytest.mark.parametrize("urdf,says", [
    ('<robot name="r"><link name="a"><visual><geometry><mesh filename="/etc/hostname"/></geometry></visual></link>'
     '</robot>', "<mesh>"),
    ('<robot name="r"><link name="a"><visual><geometry><mesh filename="file.stl"/></geometry></visual></link></robot>',
     "<mesh>"),
    ('<!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="&a;"/>', "DOCTYPE"),
    ("<html><body/></html>", "not a URDF"),
    ("not xml at all", "not XML"),
])
def test_view_loads_only_primitive_geometry(tmp_path, recorded, urdf, says):
    path = damaged.written(tmp_path / "foreign.mcap", urdf=urdf, messages=damaged.topics_of(recorded))
    refused(["view", path, "--rrd", tmp_path / "v.rrd"], says=says)
    assert not list(tmp_path.glob("v.rrd*"))


def test_a_urdf_that_is_not_utf8(tmp_path, recorded):
    path = damaged.written(tmp_path / "latin.mcap", messages=damaged.topics_of(recorded), urdf_bytes=b"<?xml \xff\xfe")
    refused(["view", path, "--rrd", tmp_path / "v.rrd"], says="UTF-8")


def test_an_lzma_chunk_is_reported_as_unsupported_compression(tmp_path, recorded):
    path = tmp_path / "lzma.mcap"
    path.write_bytes(damaged.lzma_chunk(recorded.read_bytes()))
    code, out, err = run_main(["info", path])
    assert code == 0 and "unsupported compression 'lzma'" in out and "CRC" not in out


def test_a_zstd_bomb_is_refused_in_bounded_memory(tmp_path, recorded):
    path = tmp_path / "bomb.mcap"
    path.write_bytes(damaged.zstd_bomb(recorded.read_bytes()))
    assert path.stat().st_size < recorded.stat().st_size
    # Measured as the child of a small process: a process forked from this (large) one starts with its peak.
    measure = ("import json, resource, subprocess, sys; "
               "status = subprocess.run([sys.executable, '-m', 'testbed.tools.cli', *sys.argv[1:]]).returncode; "
               "print(json.dumps([status, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss]))")
    for argv in (["info", path], ["replay", path, "--estimator", "complementary"], ["view", path, "--rrd",
                                                                                     tmp_path / "b.rrd"]):
        result = subprocess.run([sys.executable, "-c", measure, *map(str, argv)], capture_output=True, text=True,
                                env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
        status, peak_kb = json.loads(result.stdout.splitlines()[-1])
        assert "Traceback" not in result.stderr and status in (0, 2), result.stderr
        assert peak_kb < 600 * 1024, f"{argv[0]}: {peak_kb / 1024:.0f} MB"


def test_a_log_time_at_the_end_of_time(tmp_path, recorded):
    messages = damaged.topics_of(recorded)
    topic, _, data = messages[-1]
    path = damaged.written(tmp_path / "late.mcap", messages=messages + [(topic, 2**63 - 1, data)])
    code, out, _ = run_main(["info", path])
    assert code == 0 and "DAMAGED" in out and "9.2e+09" not in out.split("\n", 3)[2]


@pytest.mark.parametrize("argv", [
    ["export-urdf", "{folder}/robot.urdf"],
    ["run", "--duration", "0.1", "--metrics", "{folder}/m.json", "--out", "{tmp}/r.mcap"],
    ["run", "--duration", "0.1", "--out", "{folder}/r.mcap"],
    ["view", "{recorded}", "--rrd", "{folder}/v.rrd"],
    ["profile", "--duration", "0.1", "--json", "{folder}/p.json"],
])
def test_an_output_in_a_read_only_folder_is_refused(tmp_path, recorded, argv):
    from tests.reliability.test_environments import read_only_copy

    folder = read_only_copy(tmp_path, "read-only")
    try:
        refused([arg.format(folder=folder, tmp=tmp_path, recorded=recorded) for arg in argv], says="not writable")
    finally:
        subprocess.run(["umount", str(folder)], check=False)
    assert not list(tmp_path.glob("r.mcap*"))
