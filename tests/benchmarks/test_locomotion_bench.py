"""Locomotion benchmark (issue 21): EKF + posture controller across drawn courses, every gait, both
contact models, and long walks (testbed.tools.locobench, its report locobench_report).

- Fast: the drawn courses (ranges, directions, determinism), the cases' configs, the cache key,
  the targets' logic, the command's bad input.
- Slow (`make test`): two short real runs on 2 processes, the report's tables and plots from
  their metrics JSON, and the cache read back.
- Bench (`make bench`): the full set (about 100 min on 2 CPUs), or a reduced one through
  LOCOBENCH_SEEDS, LOCOBENCH_GAITS, LOCOBENCH_LONG_DURATION and LOCOBENCH_MAX_DURATION; it refreshes
  docs/results/locomotion.{md,csv}, docs/img/locomotion_*.png and docs/results.md, then asserts
  the issue's targets.
"""

from __future__ import annotations

import csv
import json
import math
import os

import numpy as np
import pytest

from testbed.tools import locobench, locobench_report
from testbed.tools.cli import main
from testbed.tools.locobench import COURSES, LONG, Case, CaseResult, LocoSet

SEEDS = range(40)


def features(segments):
    return [s for s in segments if s["kind"] != "flat"]


@pytest.mark.parametrize("layout", list(locobench.LAYOUTS))
def test_drawn_courses_stay_in_the_issue_ranges_and_follow_their_layout(layout):
    for index in SEEDS:
        segments, target_x = locobench.layout_course(layout, index)
        drawn = features(segments)
        assert [(s["kind"], int(np.sign(s.get("angle_deg", s.get("height", s.get("rise", 0.0)))))) for s in drawn] \
            == list(locobench.LAYOUTS[layout])
        for s in drawn:
            if s["kind"] == "ramp":
                assert 12.0 <= abs(s["angle_deg"]) <= 20.0
            elif s["kind"] == "step":
                assert 0.03 <= abs(s["height"]) <= 0.06
            elif s["kind"] == "stairs":
                assert 0.03 <= abs(s["rise"]) <= 0.05 and s["tread"] >= 0.15 and 2 <= s["steps"] <= 4
            else:
                assert 0.025 <= s["amplitude"] <= 0.035
        last_end = locobench.COURSE_START + sum(locobench.segment_length(s) for s in segments[:-1])
        assert target_x == pytest.approx(last_end + locobench.TARGET_BEYOND, abs=1e-3)


def test_courses_are_drawn_per_case_deterministically_and_differ_between_seeds():
    assert locobench.layout_course("A", 3) == locobench.layout_course("A", 3)
    courses = {json.dumps(locobench.layout_course("A", index)) for index in SEEDS}
    assert len(courses) == len(SEEDS)
    # The draws cover the ranges, not one corner of them.
    angles = [abs(s["angle_deg"]) for index in SEEDS for s in features(locobench.layout_course("B", index)[0])
              if s["kind"] == "ramp"]
    assert min(angles) < 13.5 and max(angles) > 18.5


def test_a_seed_gives_the_same_course_and_run_seed_to_every_gait_and_contact():
    cases = [locobench.course_case("C", 2, gait, contact) for gait in locobench.GAITS for contact in locobench.CONTACTS]
    assert len({json.dumps(c.config["terrain"], sort_keys=True) for c in cases}) == 1
    assert len({c.config["run"]["seed"] for c in cases}) == 1
    for case in cases:
        run, gait = case.config["run"], case.config["gait"]
        assert (run["estimator"], run["controller"], run["terrain"]) == ("ekf", "posture", "course")
        # Long enough to walk to the target at the gait's speed.
        assert run["duration"] > gait["target"][0] / gait["speed"]
        assert gait["target"][0] + 0.5 <= case.config["terrain"]["extent"][1]


def test_the_long_walks_have_ground_for_their_whole_duration():
    for name, (terrain, speed, period) in locobench.LONG_SCENARIOS.items():
        case = locobench.long_case(name)
        run, extent = case.config["run"], case.config["terrain"]["extent"]
        assert run["duration"] == 600.0 and run["gait"] == "tripod"
        assert extent[1] >= speed * 600.0 + 1.0
        stride = speed * 0.5 * case.config["gait"]["tripod_period"]
        assert stride <= case.config["gait"]["max_step_length"]
        if terrain == "course":
            segments = case.config["terrain"]["course"]
            ramps = [s for s in segments if s["kind"] == "ramp"]
            assert len(ramps) >= 10 and all(12.0 <= abs(s["angle_deg"]) <= 20.0 for s in ramps)
            rise = sum(s["length"] * math.tan(math.radians(s["angle_deg"])) for s in ramps)
            assert abs(rise) < 0.02          # every down ramp returns to the level before its up ramp
            assert locobench.COURSE_START + sum(locobench.segment_length(s) for s in segments) <= extent[1]


def test_the_full_set_builds_valid_configs_for_every_case():
    cases = LocoSet().cases()
    assert len(cases) == 3 * 10 * 3 * 2 + 3
    assert len({case.key for case in cases}) == len(cases)
    assert len({case.config["run"]["seed"] for case in cases if case.group == COURSES}) == 3 * 10


def test_the_cache_key_follows_the_config():
    case = locobench.course_case("A", 0, "tripod", "compliant")
    again = locobench.course_case("A", 0, "tripod", "compliant")
    assert case.key == again.key
    changed = Case(case.group, case.scenario, case.index, {**case.config, "run": {**case.config["run"], "seed": 1}},
                   case.terrain)
    assert changed.key != case.key


def test_a_config_file_overrides_the_defaults_in_every_case_and_enters_the_cache_key(tmp_path):
    settings = tmp_path / "shear0.toml"
    settings.write_text('[run]\nestimator = "none"\ngait = "wave"\n'
                        '[estimators.ekf]\nfoot_shear_per_newton = 0.0\n[gait]\nswing_height = 0.045\n')
    plain = LocoSet(seeds=1, layouts=("C",), gaits=("tripod", "ripple"), contacts=("dart",),
                    long_scenarios=("flat 0.1 m/s",))
    configured = LocoSet(**{**plain.__dict__, "config_file": settings})
    for before, after in zip(plain.cases(), configured.cases(), strict=True):
        assert after.config["estimators"]["ekf"]["foot_shear_per_newton"] == 0.0
        assert before.config["estimators"]["ekf"]["foot_shear_per_newton"] > 0.0
        assert after.config["gait"]["swing_height"] == 0.045
        # the case's own settings win over the file's: its gait, the EKF and the posture controller
        assert (after.config["run"]["gait"], after.config["run"]["estimator"]) == (before.config["run"]["gait"], "ekf")
        assert after.config["terrain"] == before.config["terrain"] and after.key != before.key
    assert not configured.full
    assert f"--config {settings}" in locobench_report.command_line(configured)


def test_locobench_command_rejects_a_missing_config_file_in_one_line(tmp_path, capsys):
    out, cache = tmp_path / "out", tmp_path / "cache"
    assert main(["locobench", "--out", str(out), "--cache", str(cache), "--config", str(tmp_path / "no.toml")]) == 2
    error = capsys.readouterr().err
    assert "config file not found" in error and error.count("\n") == 1 and "Traceback" not in error
    assert not out.exists() and not cache.exists()


def result(scenario: str, group: str = COURSES, **metrics) -> CaseResult:
    base = {"fell": False, "left_terrain": False, "error": None, "tilt_rms_deg": 0.2, "tilt_max_deg": 0.8,
            "edge_tilt_max_deg": 0.7, "rough_tilt_max_deg": 0.8, "height_error_rms_m": 0.002, "ik_limited_ticks": 0,
            "target_error_m": 0.01, "distance_m": 4.0, "sim_time_s": 50.0}
    config = {"run": {"duration": 50.0, "contact": "compliant", "gait": "tripod", "seed": 1}, "gait": {"speed": 0.1}}
    return CaseResult(Case(group, scenario, 0, config, "drawn"), {**base, **metrics})


def test_targets_are_met_only_when_every_run_meets_them():
    good = [result("A tripod compliant"), result("flat 0.1 m/s", LONG, tilt_rms_deg=0.25, tilt_max_deg=0.9,
                                                 target_error_m=None)]
    checks = locobench_report.target_checks(good)
    assert len(checks) == 1 + 2 + 3 + 1 and all(c.passed for c in checks), checks
    # a rough patch's tilt sets no target; an edge's does
    rough = good + [result("C ripple dart", tilt_max_deg=3.1, rough_tilt_max_deg=3.1)]
    assert all(c.passed for c in locobench_report.target_checks(rough))
    bad = good + [result("B wave dart", tilt_max_deg=2.4, edge_tilt_max_deg=2.4, target_error_m=0.045, fell=True)]
    failed = [c for c in locobench_report.target_checks(bad) if not c.passed]
    assert [c.what.split(" ")[0] for c in failed] == ["0", "course", "walk"]
    assert "while crossing a step, stair or ramp edge" in failed[1].what
    assert failed[1].detail.startswith("worst 2.40 deg (B wave dart #0); 1 of 2 runs within. Over the whole run: "
                                       "worst 2.40 deg")
    assert "worst 4.5 cm" in failed[2].detail
    # A run without metrics is never counted as met.
    missing = good + [CaseResult(good[0].case, None, "RuntimeError: boom")]
    assert not locobench_report.target_checks(missing)[0].passed


@pytest.mark.parametrize("arguments, message", [
    (["--seeds", "0"], "--seeds must be 1 ... 1000"),
    (["--gaits", "gallop"], "--gaits: unknown 'gallop'"),
    (["--layouts", "Z"], "--layouts: unknown 'Z'"),
    (["--long", "marathon"], "--long: unknown 'marathon'"),
    (["--long-duration", "5"], "--long-duration must be 10 ... 3600 s"),
    (["--layouts", "none", "--long", "none"], "nothing to run"),
])
def test_locobench_command_rejects_bad_input_in_one_line(arguments, message, tmp_path, capsys):
    out, cache = tmp_path / "out", tmp_path / "cache"
    assert main(["locobench", "--out", str(out), "--cache", str(cache), *arguments]) == 2
    error = capsys.readouterr().err
    assert message in error and error.count("\n") == 1 and "Traceback" not in error
    assert not out.exists() and not cache.exists()


@pytest.mark.parametrize("option", ["--out", "--cache"])
def test_locobench_command_refuses_a_folder_under_a_file(option, tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    folders = {"--out": tmp_path / "out", "--cache": tmp_path / "cache", option: blocker / "sub"}
    assert main(["locobench", "--seeds", "1", "--long", "none", *[str(x) for pair in folders.items() for x in pair]]) == 2
    error = capsys.readouterr().err
    assert "under a file" in error and error.count("\n") == 1
    assert blocker.read_text() == "not a folder" and not (tmp_path / "out").exists()


SMOKE = LocoSet(seeds=1, layouts=("B",), gaits=("tripod",), contacts=("compliant",),
                long_scenarios=("flat 0.1 m/s",), long_duration=10.0, max_duration=8.0)


@pytest.mark.slow
def test_report_of_real_runs_from_their_metrics_json(tmp_path):
    cache = tmp_path / "cache"
    seen = []
    first = locobench.run_cases(SMOKE, cache, workers=2, progress=lambda case: seen.append(case.label))
    assert first.simulated == 2 and sorted(seen) == sorted(c.label for c in SMOKE.cases())
    course, walk = first.results
    for r in first.results:
        on_disk = json.loads(locobench.metrics_path(r.case, cache).read_text())
        assert r.metrics == on_disk and not r.metrics["fell"] and r.metrics["error"] is None
        assert r.metrics["sim_time_s"] == pytest.approx(r.case.config["run"]["duration"], abs=2e-3)
        assert 0.0 < r.metrics["tilt_rms_deg"] <= r.metrics["tilt_max_deg"] < 10.0
    assert course.case.config["run"]["duration"] == 8.0 and course.metrics["target_error_m"] > 1.0   # cut short
    assert walk.metrics["target_error_m"] is None and 0.3 < walk.metrics["distance_m"] < 1.0

    folder = tmp_path / "report"
    locobench_report.write(first, folder)
    text = (folder / "locomotion.md").read_text()
    assert "**A reduced set**" in text
    row = next(line for line in text.splitlines() if line.startswith("| B tripod compliant |"))
    tilt_max = course.metrics["tilt_max_deg"]
    assert f"| {tilt_max:.2f} / {tilt_max:.2f} |" in row
    # 8 s of course B reach no feature (its rough patch starts 0.3 m ahead, after the start-up)
    assert course.metrics["edge_tilt_max_deg"] is None and f"| {tilt_max:.2f} / {tilt_max:.2f} | – | " in row
    assert f"| {walk.metrics['tilt_rms_deg']:.3f} |" in next(l for l in text.splitlines() if l.startswith("| flat 0.1"))
    target = next(line for line in text.splitlines() if line.startswith("| 10 s flat 0.1 m/s: tilt RMS"))
    assert target.endswith("| yes |") == (walk.metrics["tilt_rms_deg"] <= 0.3)
    for name in (locobench_report.COURSES_FIGURE, locobench_report.LONG_FIGURE):
        assert (folder / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (folder / name).stat().st_size > 10_000
    with open(folder / "locomotion.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert [float(r["tilt_max_deg"]) for r in rows] == [r.metrics["tilt_max_deg"] for r in first.results]

    again = locobench.run_cases(SMOKE, cache, workers=2)
    assert again.simulated == 0 and [r.metrics for r in again.results] == [r.metrics for r in first.results]


@pytest.mark.slow
def test_ctrl_c_stops_the_workers_and_caches_no_interrupted_run(tmp_path):
    import signal
    import time

    import psutil

    from tests.reliability.cli_process import finish, start, wait_for

    cache = tmp_path / "cache"
    process = start("locobench", "--seeds", "1", "--layouts", "A", "--gaits", "tripod", "--long", "none",
                    "--cache", str(cache), "--out", str(tmp_path / "out"))
    parent = psutil.Process(process.pid)
    wait_for(lambda: len([p for p in parent.children() if "spawn_main" in " ".join(p.cmdline())]) == 2, 60, 0.1)
    time.sleep(3.0)                         # both runs under way
    workers = parent.children(recursive=True)
    process.send_signal(signal.SIGINT)
    status, _, err = finish(process, timeout=30)
    assert status == 130 and err.rstrip().endswith("testbed: interrupted") and "Traceback" not in err
    assert not list(cache.glob("*.json")) and not (tmp_path / "out" / "locomotion.md").exists()
    psutil.wait_procs(workers, timeout=10)
    assert not [p for p in workers if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


def reduced_set_from_environment() -> LocoSet:
    """LOCOBENCH_SEEDS, LOCOBENCH_GAITS (comma-separated), LOCOBENCH_LONG_DURATION, LOCOBENCH_MAX_DURATION."""
    environment = os.environ
    full = LocoSet()
    return LocoSet(seeds=int(environment.get("LOCOBENCH_SEEDS", full.seeds)),
                   gaits=tuple(environment.get("LOCOBENCH_GAITS", ",".join(full.gaits)).split(",")),
                   long_duration=float(environment.get("LOCOBENCH_LONG_DURATION", full.long_duration)),
                   max_duration=float(environment["LOCOBENCH_MAX_DURATION"])
                   if "LOCOBENCH_MAX_DURATION" in environment else None)


@pytest.mark.bench
def test_locomotion_benchmark(request, capsys):
    if "bench" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("the locomotion benchmark: run it with -m bench (make bench)")
    from tqdm import tqdm

    loco_set = reduced_set_from_environment()
    cases = loco_set.cases()
    with capsys.disabled(), tqdm(total=len(cases), unit="run", desc="locomotion benchmark") as bar:
        result = locobench.run_cases(loco_set, workers=2, progress=lambda case: bar.update(1), cases=cases)
    locobench_report.write_docs(result)
    failed = [f"{c.what}: {c.detail}" for c in locobench_report.target_checks(result.results) if not c.passed]
    assert not failed, failed
