"""Estimator-accuracy benchmarks (issues 5, 8 and 18): walks recorded once per terrain, contact,
IMU grade, array layout, fault and seed (cached by config hash), every estimator replayed over the
same data, scored, and checked against issue 18's targets.

- The smoke set (marked slow, part of `make test`): flat ground on both contacts, the default IMU,
  seed 0, 6 s, with the quad array and a stuck gyro; three estimators. It checks the harness on
  real walks (every replay on the same data, the array layout, the fault, the cache, the report).
- The full set (marked bench, `make bench`): `bench.BenchSet()`, or the set BENCH_ARGS describes
  (the options of `testbed bench`); it refreshes docs/results.md, docs/results/estimators.* and
  docs/img/estimators_*.png before asserting the targets.
Evaluation seeds are 0-9; the estimators were tuned on seeds 100-109 (docs/estimators.md).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from testbed.tools import bench, bench_cli, bench_report
from testbed.tools.cli import main

SMOKE = bench.BenchSet(terrains=("flat",), contacts=("compliant", "dart"), grades=("default",), seeds=(0,),
                       duration=6.0, estimators=("ekf", "madgwick", "vqf"), array_terrains=("flat",),
                       faults=("gyro_stuck",), fault_terrains=("flat",), fault_seeds=(0,),
                       fault_estimators=("ekf", "vqf"))
WORKERS = 2


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def smoke(cache) -> tuple[bench.BenchResult, bench.BenchResult]:
    """The smoke set run twice on a fresh cache: recorded, then replayed from the cache."""
    return bench.run_bench(SMOKE, cache_dir=cache, workers=WORKERS), bench.run_bench(SMOKE, cache_dir=cache,
                                                                                      workers=1)


def by_walk(result: bench.BenchResult) -> dict:
    return {(r.scenario, r.estimator): r for r in result.replays}


@pytest.mark.slow
def test_every_estimator_replays_every_walk(smoke):
    first, _ = smoke
    walks = SMOKE.scenarios()
    assert len(walks) == 6 and not first.failed and first.recorded == 6
    assert {(r.scenario, r.estimator) for r in first.replays} == {(s, e) for s, names in walks.items() for e in names}
    for replay in first.replays:
        assert replay.cost["ImuSample"]["count"] == pytest.approx(1000 * SMOKE.duration, abs=2)
        assert np.isfinite(replay.metrics["roll_rmse_deg"]) and np.isfinite(replay.metrics["pitch_rmse_deg"])
        assert (replay.metrics["anees_tilt"] is not None) == (replay.estimator == "ekf")
    for contact in SMOKE.contacts:       # a loose bound: the EKF is near 0.1 deg on flat ground
        ekf = by_walk(first)[(bench.Scenario("flat", 0, SMOKE.duration, contact=contact), "ekf")]
        assert max(ekf.metrics["roll_rmse_deg"], ekf.metrics["pitch_rmse_deg"]) < 0.5, contact


@pytest.mark.slow
def test_the_array_adds_a_stream_and_changes_nothing_else(smoke):
    """The quad array's walk is the same walk (same physics, same IMU samples): an estimator that
    does not read the array scores exactly the same with it."""
    first, _ = smoke
    replays = by_walk(first)
    for contact in SMOKE.contacts:
        off = bench.Scenario("flat", 0, SMOKE.duration, contact=contact)
        on = bench.Scenario("flat", 0, SMOKE.duration, contact=contact, array="quad")
        for name in ("madgwick", "vqf"):
            assert replays[(on, name)].metrics == replays[(off, name)].metrics
        assert bench.dataset_key(bench.scenario_config(on)) != bench.dataset_key(bench.scenario_config(off))


@pytest.mark.slow
def test_a_stuck_gyro_acts_from_its_start(smoke):
    first, _ = smoke
    replays = by_walk(first)
    for contact in SMOKE.contacts:
        faulty = bench.Scenario("flat", 0, SMOKE.duration, "gyro_stuck", contact, array="quad")
        clean = replays[(faulty.reference, "vqf")].metrics
        assert replays[(faulty, "vqf")].metrics["roll_rmse_deg"] != clean["roll_rmse_deg"]
    rows = bench.summary_rows(first.replays)
    checks = bench.target_checks(rows)
    faults = [c for c in checks if c.group == "faults"]
    assert {c.where for c in faults} == {f"flat · {contact} · default · quad array · gyro_stuck (1 run)"
                                         for contact in SMOKE.contacts}
    assert {c.target for c in faults} == {"RMSE ≤ 2× fault-free", "ANEES inside the 95 % bounds"}


@pytest.mark.slow
def test_the_cache_replays_without_simulating_and_gives_the_same_figures(smoke):
    first, second = smoke
    assert second.recorded == 0 and not second.failed
    assert [r.metrics for r in second.replays] == [r.metrics for r in first.replays]


@pytest.mark.slow
def test_report_files(smoke, tmp_path):
    first, _ = smoke
    checks = bench.target_checks(bench.summary_rows(first.replays))
    bench_report.write(first, checks, tmp_path)
    text = (tmp_path / "results.md").read_text()
    assert "**Reduced set**" in text and "### flat" in text
    assert "### Accelerometer array" in text and "### Sensor faults" in text
    for contact in SMOKE.contacts:
        assert f"| flat · {contact} · default (1 run) |" in text
    for name in ("estimators_error_flat.png", "estimators_rmse.png", "estimators_nees.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    document = json.loads((tmp_path / "results.json").read_text())
    assert len(document["runs"]) == len(first.replays)
    assert (tmp_path / "results.csv").read_text().count("\n") == len(first.replays) + 1
    ekf = [row for row in document["summary"] if row["estimator"] == "ekf" and row["contact"] == "dart"
           and row["fault"] == "none" and row["array"] == "imu_only"]
    run = [run for run in document["runs"] if run["estimator"] == "ekf" and run["contact"] == "dart"
           and run["fault"] == "none" and run["array"] == "imu_only"]
    assert len(ekf) == 1 and ekf[0]["roll_rmse_deg"] == pytest.approx(run[0]["roll_rmse_deg"])


def test_walks_of_other_contacts_grades_layouts_and_faults_are_other_datasets():
    scenario = bench.Scenario("course", 0, 30.0)
    config = bench.scenario_config(scenario)
    assert config.terrain.course and config.run.contact == "compliant"
    keys = {bench.dataset_key(bench.scenario_config(s)) for s in (
        scenario, bench.Scenario("course", 0, 30.0, contact="dart"), bench.Scenario("course", 0, 30.0, grade="tactical"),
        bench.Scenario("course", 0, 30.0, array="quad"), bench.Scenario("course", 0, 30.0, "gyro_bias_jump"),
        bench.Scenario("course", 1, 30.0))}
    assert len(keys) == 6
    retuned = config.replace(estimators={"ekf": {"foot_slip_std": 0.01}})
    assert bench.dataset_key(retuned) == bench.dataset_key(config)     # tuning replays, it does not re-record
    consumer = bench.scenario_config(bench.Scenario("flat", 0, 30.0, grade="consumer"))
    assert consumer.sensors.imu.gyro.turn_on_bias > config.sensors.imu.gyro.turn_on_bias


def test_a_walk_that_failed_before_is_reported_not_simulated(tmp_path):
    scenario = bench.Scenario("flat", 0, 6.0)
    config = bench.scenario_config(scenario)
    (tmp_path / f"{bench.dataset_key(config)}.failed").write_text("flat compliant seed 0: the robot fell\n")
    result = bench.evaluate(bench.Job(scenario, config.to_dict(), ("ekf",), str(tmp_path), False))
    assert result.replays == [] and result.notes == ["flat compliant seed 0: the robot fell"] and not result.recorded
    assert not list(tmp_path.glob("*.mcap"))


def test_fault_specs_of_the_gyro_faults():
    assert bench.fault_specs("gyro_stuck", 30.0) == ["imu.gyro.stuck@12.0s+2s"]
    assert bench.fault_specs("gyro_bias_jump", 30.0) == ["imu.gyro.x.bias_step@12.0s+2s:0.5"]


def test_results_page_includes_every_fragment_verbatim(tmp_path):
    fragments = tmp_path / "results"
    fragments.mkdir()
    (fragments / "profile.md").write_text("## Profile\n\n| stage | us |\n")
    (fragments / "posture.md").write_text("## Posture\n\ntable\n")
    (fragments / "estimators.md").write_text("## Estimators\n\nmy tables\n")
    (fragments / "notes.txt").write_text("not a fragment\n")
    bench_report.write_results_page(tmp_path)
    page = (tmp_path / "results.md").read_text()
    assert page.index("my tables") < page.index("## Posture") < page.index("## Profile")
    assert "| stage | us |\n" in page and "not a fragment" not in page


@pytest.mark.parametrize("arguments, message", [
    (["--terrains", "moon"], "unknown 'moon'"),
    (["--contacts", "glue"], "unknown 'glue'"),
    (["--estimators", "ekf,kalman"], "unknown estimator 'kalman'"),
    (["--seeds", "0"], "--seeds must be at least 1"),
    (["--duration", "1"], "--duration must be at least 2 s"),
    (["--faults", "meteor"], "unknown 'meteor'"),
    (["--grades", "lunar"], "unknown sensor preset 'lunar'"),
    (["--sensors", "lunar"], "unknown sensor preset 'lunar'"),
    (["--array-terrains", "moon"], "unknown 'moon'"),
])
def test_bench_command_rejects_bad_input_in_one_line(arguments, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["bench", "--out", str(out), "--cache", str(tmp_path / "cache"), *arguments]) == 2
    error = capsys.readouterr().err
    assert message in error and error.count("\n") == 1 and "Traceback" not in error
    assert not out.exists() and not (tmp_path / "cache").exists()


def test_bench_needs_somewhere_to_write(tmp_path, capsys):
    assert main(["bench", "--cache", str(tmp_path / "cache")]) == 2
    assert "--out DIR, --docs" in capsys.readouterr().err


def test_bench_args_narrow_the_full_set():
    assert bench_cli.bench_set_from_text("") == bench.BenchSet()
    reduced = bench_cli.bench_set_from_text("--seeds 2 --terrains flat,rough --contacts dart --duration 10 "
                                            "--faults none --array-terrains none")
    assert reduced.seeds == (0, 1) and reduced.terrains == ("flat", "rough") and reduced.contacts == ("dart",)
    assert reduced.grades == bench.GRADES and not reduced.faults and not reduced.array_terrains
    assert len(reduced.scenarios()) == 2 * 2 * 3 and not reduced.is_full
    with pytest.raises(bench.UserError, match="BENCH_ARGS: unknown option '--colour'"):
        bench_cli.bench_set_from_text("--colour red")


@pytest.mark.slow
def test_bench_command_on_cached_walks(smoke, cache, tmp_path, capsys):
    """The command line reuses the smoke set's datasets (same configs, same cache): no simulation."""
    out = tmp_path / "report"
    assert main(["bench", "--terrains", "flat", "--contacts", "compliant,dart", "--grades", "default", "--seeds", "1",
                 "--duration", str(SMOKE.duration), "--estimators", "ekf,vqf", "--array-terrains", "none",
                 "--faults", "none", "--workers", "1", "--cache", str(cache), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "2 walks (2 in the cache, 0 to simulate)" in printed and "(0 simulated" in printed
    document = json.loads((out / "results.json").read_text())
    assert {(r["contact"], r["estimator"]) for r in document["runs"]} == {
        (c, e) for c in ("compliant", "dart") for e in ("ekf", "vqf")}
    assert (out / "results.md").exists() and (out / "estimators_error_flat.png").exists()


@pytest.mark.bench
def test_full_set_meets_the_estimator_targets(request):
    if "bench" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("the full benchmark: run it with -m bench (make bench)")
    bench_set = bench_cli.bench_set_from_text(os.environ.get("BENCH_ARGS", ""))
    result = bench.run_bench(bench_set, workers=WORKERS)
    checks = bench.target_checks(bench.summary_rows(result.replays))
    bench_report.write_docs(result, checks)
    failed = [f"{check.what}: {check.detail}" for check in checks if check.passed is False]
    assert not result.failed and not failed, result.failed + failed
