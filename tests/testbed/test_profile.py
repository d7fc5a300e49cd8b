"""`testbed profile`: the stage table, the JSON figures, the bare DART step, and bad input."""

import json
import tempfile
import time

import pytest

from testbed.tools.cli import main
from testbed.tools.profile import STAGES, StageClock, calibrate_wrapper


@pytest.fixture(scope="module")
def profiled(tmp_path_factory):
    """One short profile of a walking run with the EKF (the profile's defaults otherwise)."""
    out = tmp_path_factory.mktemp("profile") / "profile.json"
    code = main(["profile", "--duration", "0.3", "--repeat", "1", "--json", str(out)])
    assert code == 0
    return json.loads(out.read_text())


def test_json_holds_every_stage_and_a_consistent_realtime_factor(profiled):
    assert set(profiled["stages_ms_per_sim_s"]) == set(STAGES)
    assert all(value >= 0 for value in profiled["stages_ms_per_sim_s"].values())
    # The stages add up to the instrumented loop; the plain loop's rate is the realtime factor.
    assert sum(profiled["stages_ms_per_sim_s"].values()) == pytest.approx(profiled["instrumented_us_per_step"])
    assert profiled["realtime_factor"] * profiled["pipeline_us_per_step"] == pytest.approx(1000.0)
    assert profiled["realtime_factor"] > 0.2
    for stage in ("physics", "contact", "sensors", "estimator", "controller", "recording"):
        assert profiled["stages_ms_per_sim_s"][stage] > 0, stage
    assert profiled["config"]["estimator"] == "ekf" and profiled["config"]["controller"] == "posture"
    assert (profiled["config"]["imu_rate"], profiled["config"]["encoder_rate"], profiled["config"]["foot_rate"]) == (1000, 200, 250)


def test_bare_dart_step_is_timed_without_and_with_contacts(profiled):
    bare = profiled["bare_dart_step_us"]
    assert 1.0 < bare["no_contacts"] < profiled["pipeline_us_per_step"]
    assert bare["dart_contacts"] > 1.0
    assert profiled["dart_contacts_standing"] == 6      # one per foot on the ground
    assert profiled["ratio_to_bare_step"] == pytest.approx(profiled["pipeline_us_per_step"] / bare["no_contacts"])


def test_the_clocks_cost_a_small_part_of_the_step(profiled):
    assert 0 <= profiled["timing_overhead_us_per_step"] < 0.1 * profiled["instrumented_us_per_step"]


def test_stage_clock_adds_up_the_time_and_the_calls():
    clock = StageClock()
    nap = clock.wrap(lambda seconds: time.sleep(seconds) or seconds, "sensors")
    assert nap(0.01) == 0.01 and nap(0.02) == 0.02
    assert clock.calls["sensors"] == 2
    assert 0.03 <= clock.totals["sensors"] < 0.2
    assert 0 <= calibrate_wrapper() < 5e-6


def test_table_is_printed_and_the_temporary_recording_removed(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert main(["profile", "--duration", "0.05", "--repeat", "1", "--estimator", "none", "--terrain", "flat"]) == 0
    out = capsys.readouterr().out
    for stage in STAGES:
        assert f"\n{stage} " in out
    assert "bare DART step:" in out and "pipeline / bare step =" in out and "real time" in out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--duration", "-1"], "--duration must lie in"),
    (["--duration", "nan"], "--duration must lie in"),
    (["--duration", "abc"], "invalid float value"),
    (["--terrain", "moon"], "unknown terrain 'moon'"),
    (["--estimator", "oracle"], "unknown estimator"),
    (["--repeat", "0"], "--repeat must lie in"),
    (["--json", "{missing}/p.json"], "exists (add --force"),
    (["--json", "{dir}"], "is a directory"),
])
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path, capsys):
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "p.json").write_text("{}")          # an existing output is replaced only with --force
    args = [arg.format(missing=existing, dir=tmp_path) for arg in args]
    assert main(["profile", "--duration", "0.05", *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert message in captured.err and captured.err.count("\n") == 1
    assert list(tmp_path.iterdir()) == [existing] and (existing / "p.json").read_text() == "{}"
