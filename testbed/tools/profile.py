"""`testbed profile`: where the time of a run goes, stage by stage, against DART's bare step.

The full pipeline of `testbed run` (physics at 1 kHz, the default sensors at their rates, an
estimator, the pilot and posture controller, MCAP recording to a temporary file) runs three
times in this process:

1. a short warm-up (imports, numba's compiled kernels loading from their cache), timed apart;
2. plain, `--repeat` times: the real-time factor is the best of them (as `timeit` reports the
   minimum: other processes on the machine only ever add time);
3. once with every stage's entry point wrapped by a clock, for the stage table. The wrappers'
   own cost is measured and reported (`timing_overhead_us_per_step`).

Then DART's `world.step()` of the same robot in a tight loop, with no Python work around it:
falling free (no contacts), and standing on the terrain through DART's contact solver.
Stage times are in ms per simulated second, which at the 1 ms step is also us per step.
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path
from unittest import mock

from testbed.control.gait import GAITS
from testbed.world.terrain import TERRAINS
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.model.errors import UserError
from testbed.runtime.outputs import prepare_output

STAGES = ("physics", "contact", "sensors", "estimator", "controller", "recording", "metrics", "other")
STAGE_NOTES = {
    "physics": "DART step, servo commands, state read-out (with the hard-finger forces)",
    "contact": "contact forces applied to DART (or DART contact read-out)",
    "sensors": "IMU, encoders, foot force sensors",
    "estimator": "estimator updates, every sample",
    "controller": "pilot: odometry, gait, posture, inverse kinematics",
    "recording": "MCAP encoding and writing",
    "metrics": "support polygon, stability margin, run metrics",
    "other": "run loop, fall checks",
}
# s simulated per timed run: `make run`'s 10 s, of which the start-up (still stand, calibration
# poses, level hold: 2.5 s) is a quarter; a 3 s run was three quarters start-up, whose ticks cost half a walking one.
DEFAULT_DURATION = 10.0
MAX_DURATION = 600.0        # s
WARMUP_DURATION = 0.05      # s simulated before anything is timed
BARE_STEPS = 1000           # DART steps timed per bare-step figure, in blocks
BARE_BLOCK = 100
SETTLE_STEPS = 300          # steps of standing before the bare steps on DART contacts
CALIBRATION_CALLS = 100_000


@dataclass
class Profile:
    config: dict
    realtime_factor: float              # simulated s per wall s, full pipeline, best of the repeats
    pipeline_us_per_step: float
    stages_ms_per_sim_s: dict[str, float]
    bare_dart_step_us: dict[str, float]
    dart_contacts_standing: int
    ratio_to_bare_step: float           # pipeline / bare step without contacts (compliant) or with (dart)
    instrumented_us_per_step: float
    timing_overhead_us_per_step: float
    warmup_s: float
    repeat_walls_s: list[float] = field(default_factory=list)

    def to_json(self) -> dict:
        return asdict(self)

    def table(self) -> str:
        c = self.config
        lines = [f"testbed profile: {c['terrain']} terrain, {c['contact']} contact, {c['gait']}, estimator "
                 f"{c['estimator']}, controller {c['controller']}; {c['duration']:g} s simulated at "
                 f"{1 / c['time_step']:g} Hz, recorded to MCAP",
                 f"{'stage':<12}{'ms per sim s':>13}{'share':>8}  what"]
        total = sum(self.stages_ms_per_sim_s.values())
        for stage, value in self.stages_ms_per_sim_s.items():
            lines.append(f"{stage:<12}{value:>13.1f}{100 * value / total:>7.1f}%  {STAGE_NOTES[stage]}")
        bare = self.bare_dart_step_us
        lines += [f"{'total':<12}{total:>13.1f}   (instrumented run; timing overhead "
                  f"{self.timing_overhead_us_per_step:.1f} us per step)",
                  f"full pipeline: {self.pipeline_us_per_step:.1f} us per step, x{self.realtime_factor:.2f} real time "
                  f"(best of {len(self.repeat_walls_s)})",
                  f"bare DART step: {bare['no_contacts']:.1f} us without contacts, {bare['dart_contacts']:.1f} us "
                  f"standing on {self.dart_contacts_standing} DART contacts; pipeline / bare step = "
                  f"{self.ratio_to_bare_step:.2f}",
                  f"warm-up (imports, compiled kernels, first steps): {self.warmup_s:.2f} s"]
        return "\n".join(lines)


# --- command line ----------------------------------------------------------------------------

def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser("profile", help="time per simulated second of each stage, and DART's bare step")
    parser.add_argument("--terrain", default="step", help=f"{' | '.join(TERRAINS.names())} (default step)")
    parser.add_argument("--contact", help="compliant | dart (default: the config's)")
    parser.add_argument("--gait", default="tripod", help=f"{' | '.join(GAITS.names())} (default tripod)")
    parser.add_argument("--estimator", default="ekf", help="none | ekf | ukf | ... (default ekf)")
    parser.add_argument("--controller", help="none | posture (default posture when there is an estimator)")
    parser.add_argument("--duration", type=float, default=DEFAULT_DURATION,
                        help=f"simulated seconds per timed run (default {DEFAULT_DURATION:g})")
    parser.add_argument("--repeat", type=int, default=2, help="plain timed runs; the best counts (default 2)")
    parser.add_argument("--seed", type=int, help="seed of the run")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON here")
    parser.add_argument("--force", action="store_true", help="replace the --json file if it exists")
    parser.set_defaults(handler=cmd_profile)


def cmd_profile(args: argparse.Namespace) -> int:
    from testbed.runtime.metrics import write_metrics

    config = profile_config(args)
    if not 1 <= args.repeat <= 20:
        raise UserError(f"--repeat must lie in [1, 20], got {args.repeat}")
    if args.json is not None:
        prepare_output(args.json, "--json", args.force)
    result = profile(config, args.repeat)
    print(result.table())
    if args.json is not None:
        write_metrics(args.json, result.to_json())     # atomically, as strict JSON
        print(f"wrote {args.json}")
    return 0


def profile_config(args: argparse.Namespace) -> Config:
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION):
        raise UserError(f"--duration must lie in (0, {MAX_DURATION:g}] s, got {args.duration}")
    controller = args.controller
    if controller is None:
        controller = "posture" if args.estimator != "none" else "none"
    run = {"terrain": args.terrain, "gait": args.gait, "estimator": args.estimator, "controller": controller,
           "duration": args.duration}
    run.update({name: getattr(args, name) for name in ("contact", "seed") if getattr(args, name) is not None})
    return config_module.load(overrides={"run": run})


# --- measurements ----------------------------------------------------------------------------

def profile(config: Config, repeat: int = 2) -> Profile:
    """Warm up, time the plain pipeline `repeat` times, time its stages, time DART's bare step."""
    warmup = _timed_run(config.replace(run={"duration": WARMUP_DURATION})).whole_s
    runs = [_timed_run(config) for _ in range(repeat)]
    best = min(runs, key=lambda run: run.loop_s)
    stages, instrumented, overhead = time_stages(config)
    no_contacts, _ = bare_step_us(config, "compliant")
    dart_contacts, touching = bare_step_us(config, "dart")
    per_step = best.loop_s / best.steps * 1e6
    bare = dart_contacts if config.run.contact == "dart" else no_contacts
    return Profile(config=_describe(config), realtime_factor=best.sim_s / best.loop_s, pipeline_us_per_step=per_step,
                   stages_ms_per_sim_s=stages, bare_dart_step_us={"no_contacts": no_contacts, "dart_contacts": dart_contacts},
                   dart_contacts_standing=touching, ratio_to_bare_step=per_step / bare,
                   instrumented_us_per_step=instrumented, timing_overhead_us_per_step=overhead, warmup_s=warmup,
                   repeat_walls_s=[run.loop_s for run in runs])


def _describe(config: Config) -> dict:
    run, sensors = config.run, config.sensors
    return {"terrain": run.terrain, "contact": run.contact, "gait": run.gait, "estimator": run.estimator,
            "controller": run.controller, "duration": run.duration, "seed": run.seed, "time_step": run.time_step,
            "imu_rate": sensors.imu.rate, "encoder_rate": sensors.encoder.rate, "foot_rate": sensors.foot.rate}


@dataclass(frozen=True)
class TimedRun:
    sim_s: float        # simulated time
    steps: int          # physics steps
    loop_s: float       # wall time of the run loop (testbed.runtime.runner's wall_s)
    whole_s: float      # wall time with building the simulation and scoring the run


def _timed_run(config: Config, clock: StageClock | None = None) -> TimedRun:
    """One run recorded to a temporary MCAP file, with its stages timed by `clock` if given."""
    from datasets.recorder import McapRecorder
    from testbed.runtime.runner import run

    with tempfile.TemporaryDirectory(prefix="testbed-profile-") as folder:
        recorder = McapRecorder(Path(folder) / "profile.mcap")
        if clock is not None:
            recorder.record = clock.wrap(recorder.record, "recording")
        started = time.perf_counter()
        with clock.patched() if clock is not None else ExitStack():
            metrics = run(config, recorder).metrics
        whole = time.perf_counter() - started
    if not metrics.get("sim_steps"):
        raise RuntimeError("the profiled run simulated nothing")
    return TimedRun(metrics["sim_time_s"], metrics["sim_steps"], metrics["wall_s"], whole)


def time_stages(config: Config) -> tuple[dict[str, float], float, float]:
    """Stage times (ms per simulated s), the instrumented loop's us per step, and the part of it
    that the clocks themselves cost."""
    clock = StageClock()
    timed = _timed_run(config, clock)
    steps, wall = timed.steps, timed.loop_s
    totals = clock.totals
    stages = {
        "physics": totals["step"] - totals["contact"] + totals["truth"],
        "contact": totals["contact"],
        "sensors": totals["sensors"],
        "estimator": totals["estimator"],
        "controller": totals["pilot"],
        "recording": totals["recording"],
        "metrics": totals["metrics"],
    }
    stages["other"] = max(wall - sum(stages.values()), 0.0)
    overhead = calibrate_wrapper() * sum(clock.calls.values()) / steps
    per_step = {stage: stages[stage] / steps * 1e6 for stage in STAGES}
    return per_step, wall / steps * 1e6, overhead * 1e6


class StageClock:
    """Wraps functions so that their wall time adds up under a stage name."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = dict.fromkeys(
            ("step", "contact", "truth", "sensors", "estimator", "pilot", "recording", "metrics"), 0.0)
        self.calls: dict[str, int] = dict.fromkeys(self.totals, 0)

    def wrap(self, function, stage: str):
        totals, calls, clock = self.totals, self.calls, time.perf_counter

        def timed(*args, **kwargs):
            started = clock()
            try:
                return function(*args, **kwargs)
            finally:
                totals[stage] += clock() - started
                calls[stage] += 1
        return timed

    def patched(self) -> ExitStack:
        """Every stage's entry point wrapped, for the duration of a `with` block."""
        import testbed.runtime.runner
        from sensors.suite import SensorSuite
        from testbed.runtime.metrics import RunMetrics
        from testbed.control.pilot import Pilot
        from testbed.world.contact import CompliantContact, DartContact
        from testbed.world.simulation import Simulation

        stack = ExitStack()
        for owner, name, stage in ((Simulation, "step", "step"), (Simulation, "truth", "truth"),
                                   (CompliantContact, "apply", "contact"),
                                   (DartContact, "update", "contact"), (SensorSuite, "update", "sensors"),
                                   (Pilot, "tick", "pilot"), (RunMetrics, "add", "metrics"),
                                   (testbed.runtime.runner, "make_tick", "metrics")):
            stack.enter_context(mock.patch.object(owner, name, self.wrap(getattr(owner, name), stage)))
        stack.enter_context(mock.patch.object(testbed.runtime.runner, "make_estimator",
                                              self._timed_estimator(testbed.runtime.runner.make_estimator)))
        return stack

    def _timed_estimator(self, make):
        def make_timed(name: str, config: Config):
            estimator = make(name, config)
            estimator.update = self.wrap(estimator.update, "estimator")
            return estimator
        return make_timed


def calibrate_wrapper() -> float:
    """Seconds that one StageClock wrapper adds to a call."""
    def nothing(*args):
        return None
    timed = StageClock().wrap(nothing, "step")
    best_plain, best_timed = math.inf, math.inf
    for _ in range(3):
        started = time.perf_counter()
        for _ in range(CALIBRATION_CALLS):
            nothing(1)
        best_plain = min(best_plain, time.perf_counter() - started)
        started = time.perf_counter()
        for _ in range(CALIBRATION_CALLS):
            timed(1)
        best_timed = min(best_timed, time.perf_counter() - started)
    return max(best_timed - best_plain, 0.0) / CALIBRATION_CALLS


def bare_step_us(config: Config, contact: str) -> tuple[float, int]:
    """Median us of `world.step()` of the run's robot and terrain with `contact`, and the number of
    DART contacts at the end. With "compliant" no force is applied: the robot falls, touching
    nothing. With "dart" it first stands for SETTLE_STEPS under its servos, then keeps standing."""
    from testbed.runtime.runner import build_simulation

    sim = build_simulation(config.replace(run={"contact": contact}))
    if contact == "dart":
        for _ in range(SETTLE_STEPS):
            sim.step(sim.standing_targets)
    world, blocks = sim.world, []
    for _ in range(BARE_STEPS // BARE_BLOCK):
        started = time.perf_counter()
        for _ in range(BARE_BLOCK):
            world.step()
        blocks.append((time.perf_counter() - started) / BARE_BLOCK * 1e6)
    return statistics.median(blocks), world.getLastCollisionResult().getNumContacts()
