"""Posture control: PI loops with anti-windup, the built-in law, the foot-target transform, the
kinematic height, terrain adaptation of the gait, the loop design's margins, a posture law plugged
in through the CLI, and closed-loop runs."""

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from estimators.base import Estimate
from testbed.runtime import config
from testbed.model.errors import ConfigError, PluginFailure
from testbed.control.gait import GaitGenerator, TerrainAdaptation, Twist, walk_plane
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.control.posture import (POSTURE_LAWS, PiLoop, PiPostureLaw,
                                     PostureCorrection, PostureMeasurement, body_frame_targets, checked_correction,
                                     correction_rotation, gait_frame_positions, gait_frame_tilt, kinematic_height,
                                     tilted_targets, untilted_positions)
from testbed.runtime.runner import build_parts, run

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)
NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
DT = 0.001


def test_pi_loop_drives_a_kinematic_plant_to_zero_error():
    loop = PiLoop(kp=0.5, ki=25.0, dt=DT, limit=0.3)
    disturbance, body = 0.05, 0.0
    for _ in range(1000):
        body = disturbance + loop.update(body)     # the plant's gain is 1: body = disturbance + correction
    assert abs(body) < 1e-6 and loop.output == pytest.approx(-disturbance, abs=1e-6)


def test_pi_loop_saturates_without_winding_up_and_recovers_at_once():
    loop = PiLoop(kp=0.5, ki=25.0, dt=DT, limit=0.1)
    for _ in range(5000):                           # an error the output cannot cancel
        loop.update(1.0)
    assert loop.output == pytest.approx(-0.1)
    assert abs(loop.ki * loop.integral) < 0.1 + loop.kp      # the integral stopped near the limit
    loop.update(-0.01)                              # the error changes sign: the output leaves the limit
    assert loop.output > -0.1


def test_pi_loop_holds_on_nan_and_when_told_to():
    loop = PiLoop(kp=0.0, ki=10.0, dt=DT, limit=1.0)
    loop.update(0.2)
    before = (loop.output, loop.integral)
    loop.update(float("nan"))
    assert (loop.output, loop.integral) == before
    loop.update(0.2, hold=True)
    assert loop.integral == before[1]
    assert all(math.isfinite(v) for v in (loop.output, loop.integral))


def test_the_pi_law_runs_one_loop_per_axis_and_keeps_the_height_without_a_measurement():
    law = PiPostureLaw.from_config(CFG)
    loops = [PiLoop(CFG.posture.tilt_kp, CFG.posture.tilt_ki, CFG.run.time_step,
                    math.radians(CFG.posture.max_tilt_correction_deg), math.radians(CFG.posture.tilt_large_error_deg),
                    CFG.posture.tilt_large_kp)
             for _ in range(2)]
    height = PiLoop(CFG.posture.height_kp, CFG.posture.height_ki, CFG.run.time_step, CFG.posture.max_height_correction)
    rng = np.random.default_rng(1)
    for k in range(500):
        roll, pitch = rng.normal(0.0, 0.05, 2)
        error = None if k % 5 == 0 else rng.normal(0.0, 0.01)
        limited = k % 7 == 0
        correction = law.update(k * CFG.run.time_step, PostureMeasurement(roll, pitch, error), None, limited)
        expected = (loops[0].update(roll, limited), loops[1].update(pitch, limited),
                    height.output if error is None else height.update(error, limited))
        assert isinstance(correction, PostureCorrection) and correction == pytest.approx(expected, abs=1e-15)


def test_the_laws_registry_has_the_pi_law_and_the_config_names_it():
    assert "pi" in POSTURE_LAWS.names() and POSTURE_LAWS.resolve("pi") is PiPostureLaw
    assert CFG.posture.law == "pi"
    with pytest.raises(ConfigError, match="unknown posture law 'pd'"):
        config.load(None, {"posture": {"law": "pd"}})


def test_a_laws_answer_must_be_three_finite_numbers():
    assert checked_correction((0.01, -0.02, 0.003), "my_law") == PostureCorrection(0.01, -0.02, 0.003)
    assert checked_correction(np.array([0.0, 0.0, 0.0]), "my_law") == PostureCorrection()
    for answer, message in ((None, "returned None"), ((0.0, 0.0), "returned \\(0.0, 0.0\\), expected"),
                            ((math.nan, 0.0, 0.0), "returned a non-finite"), (("a", 0, 0), "returned")):
        with pytest.raises(PluginFailure, match=f"^posture law 'my_law' {message}"):
            checked_correction(answer, "my_law")


def test_correction_turns_the_body_and_the_inverse_is_exact():
    correction = PostureCorrection(0.05, -0.03, 0.01)
    body = body_frame_targets(NEUTRAL, correction)
    np.testing.assert_allclose(gait_frame_positions(body, correction), NEUTRAL, atol=1e-12)
    # Feet fixed on the ground: the body frame is the gait frame turned by R and raised by d.
    rotation = correction_rotation(0.05, -0.03)
    np.testing.assert_allclose(body @ rotation.T + [0, 0, 0.01], NEUTRAL, atol=1e-12)
    # A positive roll correction lowers the left feet (y > 0) relative to the body: the left side rises.
    lowered = body_frame_targets(NEUTRAL, PostureCorrection(0.05, 0.0, 0.0))[:, 2] - NEUTRAL[:, 2]
    assert np.all(np.sign(lowered[NEUTRAL[:, 1] > 0.01]) == -1)


def test_the_compiled_correction_is_the_readable_one():
    rng = np.random.default_rng(0)
    for _ in range(1000):
        correction = PostureCorrection(*rng.normal(0.0, 0.1, 3))
        cr, sr, cp, sp = math.cos(correction.roll), math.sin(correction.roll), math.cos(correction.pitch), \
            math.sin(correction.pitch)
        rotation = np.array([[cp, sp * sr, sp * cr], [0.0, cr, -sr], [-sp, cp * sr, cp * cr]])
        np.testing.assert_allclose(correction_rotation(correction.roll, correction.pitch), rotation, rtol=0, atol=1e-15)
        feet = NEUTRAL + rng.normal(0.0, 0.02, NEUTRAL.shape)
        np.testing.assert_allclose(tilted_targets(feet, *correction), body_frame_targets(feet, correction),
                                   rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(untilted_positions(feet, *correction, np.empty((6, 3))),
                                   gait_frame_positions(feet, correction), rtol=1e-12, atol=1e-15)


def test_kinematic_height_of_a_level_stance_and_of_a_tilted_body():
    joints = inverse_kinematics_all(GEOM, NEUTRAL)
    stance = np.ones(6, bool)
    assert kinematic_height(GEOM, joints, stance, 0.0, 0.0, CFG.robot.foot_radius) == pytest.approx(
        CFG.robot.stance_height, abs=1e-9)
    # The same body pitched by 5 degrees over the same ground: the feet seen from the body turn.
    pitch = math.radians(5.0)
    feet = body_frame_targets(NEUTRAL, PostureCorrection(0.0, pitch, 0.0))
    tilted = inverse_kinematics_all(GEOM, feet)
    assert kinematic_height(GEOM, tilted, stance, 0.0, pitch, CFG.robot.foot_radius) == pytest.approx(
        CFG.robot.stance_height, abs=1e-6)
    assert kinematic_height(GEOM, joints, np.array([1, 1, 0, 0, 0, 0], bool), 0, 0, 0.01) is None


ADAPT = TerrainAdaptation(search_speed=0.1, search_depth=0.06, touchdown_phase=0.5, plane_time_constant=0.3)


def walk(gait, ticks, ground_of):
    """Step the gait over ground whose height under each foot (in the start's frame) is
    ground_of(tick); the foot sensors report feet at or below it. Returns the feet per tick."""
    out, airborne = [], []
    for k in range(ticks):
        contact = gait.state.feet[:, 2] <= ground_of(k) - gait.frame_drop + 1e-9
        out.append(gait.step((k + 1) * DT, DT, Twist(vx=0.1), contact, gait.state.feet.copy()))
        airborne.append(gait.searching.copy())
    walk.searching = np.array(airborne)
    return np.array(out)


def ground_at(depth):
    """Ground `depth` below the neutral stance under legs 1 and 6 (the front), level elsewhere."""
    floor = NEUTRAL[:, 2] - np.array([depth, 0, 0, 0, 0, depth])
    return lambda k: floor


def test_a_foot_that_finds_no_ground_reaches_down_while_the_gait_clock_waits():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, ADAPT)
    feet = walk(gait, 3000, ground_at(0.03))
    assert gait.waited > 0.2                       # two front feet reaching 3 cm lower at 0.1 m/s
    # The front legs stand 3 cm lower than planned once they found it, never below the search floor.
    lowest = feet[:, [0, 5], 2].min(axis=0)
    assert np.all(lowest > NEUTRAL[[0, 5], 2] - 0.03 - ADAPT.search_depth)
    # While a foot searches, no other foot moves: the clock and the body wait for it.
    searching = walk.searching.any(axis=1)
    assert searching.sum() > 200
    still = ~walk.searching[1:] & searching[1:, None]
    assert np.all(np.abs(np.diff(feet, axis=0))[still] < 1e-12)


def test_a_foot_that_touches_early_stops_there():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, ADAPT)
    feet = walk(gait, 3000, ground_at(-0.02))      # the front ground is 2 cm higher
    # The front feet land on the higher ground where they touch it and never push below it.
    front_floor = NEUTRAL[[0, 5], 2] + 0.02
    assert np.all(feet[-1, [0, 5], 2] - front_floor > -1e-3 - abs(gait.frame_drop))
    assert np.all(np.diff(feet[:, 0, 2])[np.abs(np.diff(feet[:, 0, 2])) > 0].size > 0)


def test_the_gait_frame_follows_the_stance_plane_down_a_step():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, ADAPT)
    feet = walk(gait, 6000, lambda k: NEUTRAL[:, 2] - (0.04 if k > 500 else 0.0))
    # Every foot found the ground 4 cm lower; the walk plane brought the body down with it.
    assert gait.frame_drop == pytest.approx(-0.04, abs=0.003)
    stance = ~gait.state.swinging
    assert feet[-1, stance, 2].mean() == pytest.approx(NEUTRAL[stance, 2].mean(), abs=0.003)


@pytest.mark.parametrize("axis", ["roll", "pitch", "height"])
def test_designed_loops_have_the_required_margins(axis):
    from testbed.tools.posture_design import analyse
    report = analyse(CFG, axis)
    assert 0.8 < report.plant.gain < 1.2 and 0.005 < report.plant.time_constant < 0.05
    assert report.gain_margin_db >= 6.0 and report.phase_margin_deg >= 45.0
    if axis != "height":
        # beyond tilt_large_error_deg the tilt loops' proportional gain is tilt_large_kp: margins there too
        from testbed.tools.posture_design import margins, pi_controller
        dt = CFG.run.time_step
        gain_margin, phase_margin, _, _ = margins(pi_controller(CFG.posture.tilt_large_kp, CFG.posture.tilt_ki, dt)
                                                  * report.plant.discrete(dt))
        assert 20.0 * math.log10(gain_margin) >= 6.0 and phase_margin >= 45.0


def test_pi_loop_answers_the_part_of_an_error_beyond_large_error_with_large_kp():
    loop = PiLoop(kp=0.5, ki=0.0, dt=DT, limit=1.0, large_error=0.01, large_kp=3.0)
    assert loop.update(0.004) == pytest.approx(-0.002)              # within: kp e
    assert loop.update(0.03) == pytest.approx(-(0.5 * 0.03 + 2.5 * 0.02))
    assert loop.update(-0.03) == pytest.approx(0.5 * 0.03 + 2.5 * 0.02)
    assert PiLoop(kp=0.5, ki=0.0, dt=DT, limit=1.0).update(0.03) == pytest.approx(-0.015)   # no large_kp: linear


def slide_on_the_identified_plant(loop: PiLoop) -> tuple[float, float]:
    """(peak, final) true tilt, deg, of the identified tilt plant (docs/control.md: unit gain,
    15 ms lag, 1 ms dead time) under `loop` while a foot slides off an edge's corner: 5 deg of
    tilt over 80 ms, from 50 ms on, 0.4 s in all."""
    turned, pending, peak = 0.0, [0.0], 0.0
    for k in range(400):
        slide = math.radians(5.0) * min(max((k * DT - 0.05) / 0.08, 0.0), 1.0)
        tilt = slide + turned
        peak = max(peak, abs(tilt))
        pending.append(loop.update(tilt))
        turned += (pending.pop(0) - turned) * DT / 0.015
    return math.degrees(peak), math.degrees(tilt)


def test_the_tilt_loops_catch_a_slide_off_a_corner_with_their_large_error_gain():
    posture = CFG.posture
    limit = math.radians(posture.max_tilt_correction_deg)
    linear = slide_on_the_identified_plant(PiLoop(posture.tilt_kp, posture.tilt_ki, DT, limit))
    law = PiPostureLaw.from_config(CFG).roll
    assert (law.large_error, law.large_kp) == (math.radians(posture.tilt_large_error_deg), posture.tilt_large_kp) \
        == (math.radians(0.2), 3.0)                          # the gain the slide figures below are for
    caught = slide_on_the_identified_plant(law)
    assert linear[0] > 2.0 and caught[0] < 1.3              # deg: 2.08 and 1.20
    assert abs(linear[1]) < 0.2 and abs(caught[1]) < 0.2      # both back within 0.2 deg by 0.4 s


def test_posture_needs_an_attitude_estimator():
    with pytest.raises(ConfigError, match="needs an attitude estimator"):
        config.load(None, {"run": {"controller": "posture", "estimator": "none"}})


@pytest.mark.slow
def test_stepping_down_with_posture_control_keeps_the_body_level():
    """The front legs cross the 4 cm step between 4.2 and 5.7 s: the body stays within 2 degrees."""
    cfg = config.load(None, {"run": {"terrain": "step", "gait": "tripod", "estimator": "ekf",
                                     "controller": "posture", "duration": 6.2, "seed": 3}})
    controlled = run(cfg).metrics
    uncontrolled = run(cfg.replace(run={"controller": "none"})).metrics
    assert not controlled["fell"] and controlled["tilt_max_deg"] < 2.0
    assert uncontrolled["tilt_max_deg"] > 2 * controlled["tilt_max_deg"]
    assert controlled["ik_limited_ticks"] == 0


LAWS_MODULE = textwrap.dedent('''
    """Posture laws of a user's own, for the plug point test."""
    import atexit
    import json
    import math
    import os

    from testbed.control.posture import PostureCorrection, PostureLaw


    class Rolled(PostureLaw):
        """Always 3 degrees of roll, nothing else; writes how often and from when it was asked."""

        def __init__(self):
            self.times = []
            atexit.register(self.write)

        def update(self, t, measurement, estimate, limited):
            assert estimate is not None and not hasattr(estimate, "body_position")     # an estimate, not truth
            self.times.append(t)
            return PostureCorrection(roll=math.radians(3.0))

        def write(self):
            with open(os.environ["LAW_LOG"], "w") as log:
                json.dump({"calls": len(self.times), "first": self.times[0] if self.times else None}, log)


    class Broken(PostureLaw):
        def update(self, t, measurement, estimate, limited):
            raise RuntimeError("no posture today")


    class NotALaw:
        pass
''')


def run_with_law(tmp_path, law, terrain="slope", duration=None):
    """`testbed run` in a new process with `posture.law = law` (the laws module on PYTHONPATH):
    (return code, stderr, metrics or None, the Recording law's log or None)."""
    (tmp_path / "my_laws.py").write_text(LAWS_MODULE)
    metrics, log = tmp_path / f"{law.replace(':', '_')}.json", tmp_path / "law.json"
    duration = duration or CFG.gait.duration_to_walk(1.0)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(Path(__file__).parents[2])]),
               LAW_LOG=str(log))
    result = subprocess.run([sys.executable, "-m", "testbed.tools.cli", "run", "--terrain", terrain,
                             "--gait", "tripod", "--estimator", "ekf", "--controller", "posture",
                             "--duration", str(duration), "--set", f"posture.law={law}", "--metrics", str(metrics),
                             "--out", str(tmp_path / "run.mcap"), "--force"], capture_output=True, text=True, env=env)
    return (result.returncode, result.stderr, json.loads(metrics.read_text()) if metrics.exists() else None,
            json.loads(log.read_text()) if log.exists() else None)


@pytest.mark.slow
def test_a_posture_law_of_ones_own_replaces_the_pi_law(tmp_path):
    """A law that always commands 3 degrees of roll tilts the body by that much; the pilot asks it
    once a tick from the end of the start-up on. The built-in law keeps the body level."""
    code, err, rolled, log = run_with_law(tmp_path, "my_laws:Rolled", terrain="flat")
    assert code == 0, err
    assert log["calls"] == pytest.approx(1.0 / CFG.run.time_step, abs=2)      # one second after the start-up
    assert log["first"] == pytest.approx(CFG.gait.startup_time(CFG.gait.duration_to_walk(1.0)), abs=2 * CFG.run.time_step)
    assert rolled["tilt_max_deg"] == pytest.approx(3.0, abs=0.5) and rolled["tilt_rms_deg"] > 2.0
    code, err, pi, _ = run_with_law(tmp_path, "pi", terrain="flat")
    assert code == 0, err
    assert pi["tilt_max_deg"] < 1.0


@pytest.mark.slow
def test_bad_posture_laws_are_reported_in_one_line(tmp_path):
    """Before the run (exit 2) or, for a law that raises, when it first runs (exit 1)."""
    for law, code, message in (("my_laws:Missing", 2, "has no 'Missing'"),
                               ("my_laws:NotALaw", 2, "is not a subclass of testbed.PostureLaw"),
                               ("nowhere:Law", 2, "no module named 'nowhere'"),
                               ("my_laws:Broken", 1, "RuntimeError: no posture today")):
        returned, err, _, _ = run_with_law(tmp_path, law, terrain="flat")
        # (numba may warn while it compiles into a cold cache)
        reported = [line for line in err.splitlines() if line.startswith("testbed: ")]
        assert returned == code and len(reported) == 1 and "Traceback" not in err, (law, err)
        assert "posture law" in reported[0] and message in reported[0], reported


def test_the_gait_frame_tilt_is_the_body_attitude_less_the_correction():
    # A body pitched 3 deg with respect to gravity that the correction pitches 1 deg in its gait
    # frame: the frame itself is pitched 2 deg.
    roll, pitch = gait_frame_tilt(0.0, math.radians(3.0), 0.0, math.radians(1.0))
    assert math.degrees(pitch) == pytest.approx(2.0, abs=1e-12) and roll == pytest.approx(0.0, abs=1e-15)
    # For roll and pitch together the frame is R(body) R(correction)^T, to first order the difference.
    roll, pitch = gait_frame_tilt(0.02, -0.03, 0.005, 0.01)
    frame = correction_rotation(0.02, -0.03) @ correction_rotation(0.005, 0.01).T
    np.testing.assert_allclose(correction_rotation(roll, pitch)[2], frame[2], rtol=0, atol=1e-12)
    assert roll == pytest.approx(0.015, abs=5e-4) and pitch == pytest.approx(-0.04, abs=5e-4)


def test_turning_the_gait_frame_turns_its_targets_and_moves_search_floors_with_them():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, ADAPT)
    gait.search_floor[:] = NEUTRAL[:, 2] - 0.06
    turn = correction_rotation(0.0, math.radians(2.0))
    gait.rotate(turn)
    np.testing.assert_allclose(gait.state.feet, NEUTRAL @ turn.T, rtol=0, atol=1e-15)
    np.testing.assert_allclose(gait.search_floor, gait.state.feet[:, 2] - 0.06, rtol=0, atol=1e-15)


STEPS = TerrainAdaptation(search_speed=0.1, search_depth=0.06, touchdown_phase=0.5, plane_time_constant=0.3,
                          clearance=0.02, max_swing_height=0.08, edge_margin=0.03)


def test_a_swing_behind_a_higher_foothold_on_its_side_lifts_to_clear_it():
    """The front feet stand 5 cm higher (a step): the middle legs, whose swings start behind
    them, lift 5 cm + the 2 cm clearance; the front feet, with nothing ahead, lift 5 cm."""
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPS)
    walk(gait, 4000, ground_at(-0.05))
    lift = gait.state_record["lift"][0]
    assert lift[[1, 4]] == pytest.approx(0.07, abs=2e-3)
    assert lift[[0, 5]] == pytest.approx(0.05, abs=1e-12)
    # Never above the highest swing the legs reach.
    higher = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPS)
    walk(higher, 4000, ground_at(-0.075))
    assert higher.state_record["lift"][0].max() == pytest.approx(0.08, abs=1e-12)


def test_a_step_the_feet_cannot_clear_or_reach_down_to_is_refused():
    base = {"run": {"terrain": "step", "controller": "posture", "estimator": "ekf"}}
    config.load(None, {**base, "terrain": {"step_height": 0.06}})
    config.load(None, {**base, "terrain": {"step_height": -0.08}})
    with pytest.raises(ConfigError, match="higher than the feet can clear: at most 0.06 m"):
        config.load(None, {**base, "terrain": {"step_height": 0.065}})
    with pytest.raises(ConfigError, match="deeper than the feet reach down: at most 0.08 m"):
        config.load(None, {**base, "terrain": {"step_height": -0.085}})
    rough = {"run": {**base["run"], "terrain": "rough"}}
    config.load(None, {**rough, "terrain": {"rough_amplitude": 0.035}})
    with pytest.raises(ConfigError, match="rough_amplitude 0.045 m is more than the feet can clear"):
        config.load(None, {**rough, "terrain": {"rough_amplitude": 0.045}})


@pytest.mark.parametrize("key, value", [("load_time", -0.01), ("load_time", 0.6),
                                        ("load_preload", -0.001), ("load_preload", 0.02)])
def test_a_load_transfer_outside_its_range_is_refused(key, value):
    with pytest.raises(ConfigError, match=f"posture.{key} must lie in"):
        config.load(None, {"posture": {key: value}})


WALK = {"run": {"gait": "tripod", "estimator": "ekf", "controller": "posture"}}


def recording_corrections(cfg):
    """Run `cfg`, keeping the pilot's posture correction of every tick: (metrics, (n, 3), pilot)."""
    parts = build_parts(cfg)
    pilot, corrections = parts.controller, []
    tick = pilot.tick

    def recorded(t, samples, estimate):
        targets = tick(t, samples, estimate)
        corrections.append(tuple(pilot.correction))
        return targets
    pilot.tick = recorded
    return run(cfg, parts=parts).metrics, np.array(corrections), pilot


@pytest.mark.slow
def test_on_level_ground_the_posture_correction_and_the_walk_plane_stay_level():
    """Before the gait frame was levelled the pitch correction ramped at about -0.3 deg/s
    (-4.3 deg at 15 s, at its 15 deg limit by 38 s) while the stance plane tilted the other way."""
    cfg = config.load(None, {"run": {**WALK["run"], "terrain": "flat", "duration": 15.0, "seed": 5}})
    metrics, corrections, pilot = recording_corrections(cfg)
    last_five_seconds = np.degrees(np.abs(corrections[-5000:, :2]))
    assert last_five_seconds.max() < 1.0
    gait = pilot.gait
    _, slope_x, slope_y = walk_plane(gait.state.feet, ~gait.state.swinging, 0.0)
    assert math.degrees(math.atan(math.hypot(slope_x, slope_y))) < 1.0
    assert not metrics["fell"] and metrics["tilt_max_deg"] < 1.0 and metrics["tilt_rms_deg"] < 0.3


@pytest.mark.slow
@pytest.mark.parametrize("height", [0.06, -0.06])
def test_a_6_cm_step_is_crossed_without_falling(height):
    """Every leg crosses the step by 10 s (up: the front feet at about 4 s, the rear by 9 s)."""
    cfg = config.load(None, {"run": {**WALK["run"], "terrain": "step", "duration": 10.0, "seed": 1},
                             "terrain": {"step_height": height}})
    metrics = run(cfg).metrics
    assert not metrics["fell"] and metrics["tilt_max_deg"] < 6.0


def test_reach_room_is_how_far_the_lowest_placed_foot_can_still_go_down():
    from testbed.control.pilot import reach_room
    geometry = LegGeometry.from_config(CFG.robot)
    reach = geometry.femur + geometry.tibia
    feet = geometry.base_positions.copy()
    outward = np.column_stack([np.cos(geometry.base_angle), np.sin(geometry.base_angle)])
    feet[:, :2] += 0.12 * outward
    feet[:, 2] = -0.09
    below = math.sqrt(reach ** 2 - 0.12 ** 2)               # the lowest a foot 12 cm out can be
    assert reach_room(feet, geometry.arrays, reach) == pytest.approx(below - 0.09, abs=1e-12)
    feet[4, 2] = -below - 0.015                             # one foot 1.5 cm out of reach
    assert reach_room(feet, geometry.arrays, reach) == pytest.approx(-0.015, abs=1e-12)
    feet[4, 2] += 0.015
    assert reach_room(feet, geometry.arrays, reach) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("angle", [20.0, -20.0])
def test_the_body_crouches_so_that_the_legs_reach_down_a_20_degree_ramp(angle):
    """A level body on a 20 degree ramp: the downhill legs at the end of their stride (the rear
    legs walking up, the front legs walking down) reach past the legs' length unless it lowers."""
    course = [{"kind": "flat", "length": 0.6}, {"kind": "ramp", "length": 0.5, "angle_deg": angle},
              {"kind": "flat", "length": 2.0}]
    cfg = config.load(None, {"run": {**WALK["run"], "terrain": "course", "duration": 11.0, "seed": 7},
                             "terrain": {"course": course}})
    crouched = run(cfg).metrics
    upright = run(cfg.replace(posture={"max_crouch": 0.0})).metrics
    assert not crouched["fell"] and crouched["ik_limited_ticks"] == 0 and crouched["tilt_max_deg"] < 1.5
    assert upright["ik_limited_ticks"] > 200
    assert crouched["height_error_rms_m"] < 0.008


@pytest.mark.slow
def test_the_body_crouches_so_that_the_wave_gaits_rear_legs_reach_down_the_stairs():
    """Up three 4.4 cm stairs on 16 cm treads in the wave gait: at the end of its long stance a
    rear foot stands a rise below the front feet and its leg reaches past its length unless the
    body lowers by more than 3 cm."""
    course = [{"kind": "flat", "length": 0.8}, {"kind": "stairs", "steps": 3, "rise": 0.044, "tread": 0.161},
              {"kind": "flat", "length": 1.0}]
    cfg = config.load(None, {"run": {**WALK["run"], "gait": "wave", "terrain": "course", "duration": 40.0, "seed": 1},
                             "gait": {"speed": 0.04}, "terrain": {"course": course}})
    crouched = run(cfg).metrics
    shallow = run(cfg.replace(posture={"max_crouch": 0.03})).metrics
    assert not crouched["fell"] and crouched["ik_limited_ticks"] == 0 and crouched["edge_tilt_max_deg"] < 1.0
    assert shallow["ik_limited_ticks"] > 300 and shallow["edge_tilt_max_deg"] > 1.2


@pytest.mark.parametrize("angle", [20.0, -20.0])
def test_the_body_stands_low_enough_through_the_calibration_poses_on_a_20_degree_slope(angle):
    """Standing on a 20 degree slope, the 12 degree calibration poses put the downhill feet past the
    legs' reach unless the body stands lower through them; it lowers with its start-up rise, by
    the same amount through every pose."""
    cfg = config.load(None, {"run": {**WALK["run"], "terrain": "slope", "duration": 2.4, "seed": 3},
                             "terrain": {"slope_deg": angle}})
    parts = build_parts(cfg)
    pilot, crouches = parts.controller, []
    tick = pilot.tick

    def recorded(t, samples, estimate):
        joints = tick(t, samples, estimate)
        crouches.append((t, pilot.crouch))
        return joints

    pilot.tick = recorded
    crouched = run(cfg, parts=parts).metrics
    upright = run(cfg.replace(posture={"max_crouch": 0.0})).metrics
    times, depth = np.array(crouches).T
    poses = np.array([pilot.startup.rise(t) == 1.0 for t in times]) & (times < pilot.startup_time)
    assert crouched["ik_limited_ticks"] == 0 and upright["ik_limited_ticks"] > 300
    assert 0.0 < depth[poses].min() == depth[poses].max() <= cfg.posture.max_crouch


def test_the_height_is_not_measured_while_fewer_than_three_feet_stand():
    """An estimator's body height is its last support-plane fit's while fewer than three feet are
    down (a DART stand rests on two diagonal feet): the law gets no height error then, and holds
    its height instead of integrating a difference the body has moved from."""
    cfg = config.load(None, {"run": {**WALK["run"], "terrain": "flat", "duration": 1.0}})
    pilot = build_parts(cfg).controller
    pilot.latest_estimate = Estimate(3.0, np.array([0.0, 0.0, 0.0, 1.0]), 0.0, 0.0, 0.0, terrain_roll=0.0,
                                     terrain_pitch=0.0, body_height=cfg.robot.stance_height + 0.01)
    pilot.foot_contact[:] = True
    assert pilot._posture_measurement(None).height_error == pytest.approx(0.01)
    pilot.foot_contact[:] = [True, False, False, True, True, False]
    assert pilot._posture_measurement(None).height_error == pytest.approx(0.01)
    pilot.foot_contact[:] = [True, False, False, True, False, False]
    assert pilot._posture_measurement(None).height_error is None
    pilot.latest_estimate = Estimate(3.0, np.array([0.0, 0.0, 0.0, 1.0]), 0.0, 0.0, 0.0)
    assert pilot._posture_measurement(None).height_error is None       # the encoders' plane alike
    pilot.foot_contact[:] = True
    assert abs(pilot._posture_measurement(None).height_error) < 0.005
