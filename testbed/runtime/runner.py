"""The run loop: one scenario from config to metrics.

One tick per physics step, data flowing one way: simulation -> sensors -> pilot (estimator,
odometry, gait, IK) -> joint commands for the next step. Ground truth goes only to the metrics
and to the recorder beside the loop.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import ContextManager, NamedTuple

import numpy as np
from numba.core.event import TimingListener, install_listener

from estimators.base import Estimate, Estimator, samples_for
from estimators.registry import NONE as NO_ESTIMATOR
from estimators.registry import make_estimator
from sensors.suite import SensorSuite
from testbed.control.command import Command
from testbed.control.controller import CONTROLLERS, Controller, checked_targets
from testbed.control.pilot import Pilot
from testbed.model.errors import PluginError, PluginFailure, SimulationDiverged
from testbed.runtime.garbage import older_objects_left_alone
from testbed.runtime.interrupts import held_interrupts
from testbed.runtime.metrics import RunMetrics
from testbed.runtime.recording import NullRecorder, Recorder, Tick
from testbed.world.simulation import FALL_TILT, Simulation
from testbed.world.records import raw
from testbed.world.stability import (CONTACT_DEBOUNCE, GROUND_TOLERANCE, resting_feet, stance_support,
                                     stance_support_on_terrain, support_record, support_view)
from testbed.world.terrain import TERRAIN_STREAM, Terrain, make_terrain

FALL_CHECK_PERIOD = 10   # physics steps between ground-touch checks of the body
GC_ALLOCATIONS = 20_000  # container objects made between two collections of the youngest generation in a run
ARRIVAL_SETTLE = 2.0      # s a run with gait.end_at_arrival goes on after the controller arrived: the body comes to rest


@dataclass
class RunOutcome:
    metrics: dict
    error: str | None = None        # set when the run stopped early (divergence, a failing plugin, interrupt)
    interrupted: bool = False
    note: str | None = None         # why a run that went well ended early (the robot left the terrain)


def build_simulation(config, terrain: Terrain | str | None = None) -> Simulation:
    """The world of `config`, on the terrain it names (or on `terrain`, a spec or an instance)."""
    if not isinstance(terrain, Terrain):
        streams = np.random.SeedSequence(config.run.seed).spawn(TERRAIN_STREAM + 1)
        spec = config.run.terrain if terrain is None else terrain
        terrain = make_terrain(spec, config, np.random.default_rng(streams[TERRAIN_STREAM]))
    return Simulation(config, terrain)


class SupportTracker:
    """The support polygon of the stance feet: the feet on the ground. A touch within
    CONTACT_DEBOUNCE counts, so a rigid contact's one-step chatter is not a lift-off, and so does
    a foot the gait holds in stance within GROUND_TOLERANCE of the ground: DART's rigid contact
    lets loaded feet spring off by a fraction of a millimetre for a few steps after an impact."""

    def __init__(self, terrain, foot_radius: float):
        self.terrain = terrain
        self._support = support_record(CONTACT_DEBOUNCE, foot_radius, GROUND_TOLERANCE)
        self.last_touch = support_view(self._support)["last_touch"]     # a view: the kernels update it
        self._not_resting = np.zeros(6, dtype=bool)
        rule = terrain.candidate_rule()
        self._boxes, self._rule = raw(terrain.boxes.records), None if rule is None else raw(rule)

    def polygon_and_margin(self, truth, swinging: np.ndarray) -> tuple[np.ndarray, float]:
        """The support polygon and the centre of mass's stability margin in it: one compiled call
        which, when a stance foot is late, asks the terrain whether it rests on the ground (a
        terrain with candidate boxes of its own names them in Python, between two compiled calls)."""
        if self._rule is not None:
            return stance_support_on_terrain(self._support, truth.t, truth.foot_contact, swinging,
                                             truth.foot_positions, truth.com_position, self._boxes, self._rule)
        args = (self._support, truth.t, truth.foot_contact, swinging, truth.foot_positions, truth.com_position)
        polygon, margin, late_bits = stance_support(*args, self._not_resting)
        if late_bits:
            candidates = np.ascontiguousarray(self.terrain.candidates(truth.foot_positions), dtype=np.int64)
            resting = resting_feet(self._support, truth.foot_positions, late_bits, self._boxes, candidates)
            polygon, margin, _ = stance_support(*args, resting)
        return polygon, margin


class Arrival:
    """When the controller said it arrived (`Controller.arrived`) on a walk to `gait.target`, and
    whether a run that `gait.end_at_arrival` ends has gone on ARRIVAL_SETTLE since."""

    def __init__(self, config, controller: Controller, spec: str):
        self.arrived = _guarded(controller.arrived, spec, "arrived") if config.gait.target else None
        self.ends = config.gait.end_at_arrival
        self.time: float | None = None      # s

    def settled(self, t: float) -> bool:
        if self.arrived is None:
            return False
        if self.time is None and self.arrived():
            self.time = t
        return self.ends and self.time is not None and t >= self.time + ARRIVAL_SETTLE


def beyond_footprint(truth, footprint: tuple[float, float, float, float]) -> bool:
    """Whether the body's centre or a foot's centre lies beyond the built terrain (x_min, x_max,
    y_min, y_max), seen from above."""
    x_min, x_max, y_min, y_max = footprint
    points = truth.foot_positions.tolist()      # seven points: plain Python is cheaper than numpy here
    points.append(truth.body_position.tolist())
    return any(not (x_min <= x <= x_max and y_min <= y <= y_max) for x, y, _ in points)


def left_terrain_note(truth) -> str:
    x, y = truth.body_position[:2]
    return (f"the robot left the built terrain at t = {truth.t:.3f} s (body at x = {x:.2f}, y = {y:.2f} m): "
            f"the run ends here")


def make_tick(sim: Simulation, truth, samples, command, estimates, support: SupportTracker) -> Tick:
    polygon, margin = support.polygon_and_margin(truth, command.swinging)
    # Positional: a named tuple built from keywords costs twice as much, at every step.
    return Tick(truth, sim.body_quaternion(), sim.contacts(), polygon, margin, samples, estimates, command)


def true_roll_pitch(truth) -> tuple[float, float]:
    """Roll and pitch (ZYX) of the true body attitude: the test-only attitude for the posture loop."""
    rotation = truth.body_rotation
    return float(np.arctan2(rotation[2, 1], rotation[2, 2])), float(-np.arcsin(np.clip(rotation[2, 0], -1.0, 1.0)))


def is_interrupt(error: BaseException | None) -> bool:
    """Ctrl-C, also when it landed in a Python callback of numba-compiled code (numba boxes the
    arrays a kernel returns through one), which reports it as a SystemError caused by it."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


@contextmanager
def fewer_garbage_collections() -> Iterator[None]:
    """Python's cycle collector, tuned for the run loop and restored afterwards. The loop makes
    tens of container objects a step (the truth's and the ticks' named tuples, samples, messages),
    most of which the recorder and the metrics keep: with the default thresholds the collector
    walked them every 700 allocations, and now and then the ~160k objects of the imported
    libraries too, a noticeable share of the loop's time. The objects made
    before the run are left out of collections (`older_objects_left_alone`), and the youngest generation is
    collected every GC_ALLOCATIONS allocations. The loop makes no cyclic garbage of note; the
    results do not depend on when it is collected."""
    thresholds = gc.get_threshold()
    gc.set_threshold(GC_ALLOCATIONS, *thresholds[1:])
    try:
        with older_objects_left_alone():
            yield
    finally:
        gc.set_threshold(*thresholds)


def compilation_timer(listener: TimingListener) -> ContextManager[TimingListener]:
    """Measures into `listener` the time numba spends compiling kernels meanwhile (`.duration`
    once `.done`): a run that compiles reports it as `compile_s` and leaves it out of `wall_s`
    and `realtime_factor`. Kernels loaded from numba's cache do not count."""
    return install_listener("numba:compile", listener)


class Parts(NamedTuple):
    """What one run is made of: the world, the robot's sensors and its onboard software."""
    sim: Simulation
    sensors: SensorSuite
    estimator: Estimator | None
    controller: Controller
    estimator_spec: str
    controller_spec: str


def build_parts(config, estimator: Estimator | str | None = None, controller: Controller | str | None = None,
                terrain: Terrain | str | None = None) -> Parts:
    """The simulation, the sensors, and the estimator, controller and terrain named in `config.run`
    (or given here, as specs or instances), the controller started in the robot's start pose."""
    estimator_spec, estimator = _part(estimator, config.run.estimator, Estimator)
    controller_spec, controller = _part(controller, config.run.controller, Controller)
    if isinstance(estimator, str):
        estimator = None if estimator == NO_ESTIMATOR else make_estimator(estimator, config)
    if isinstance(controller, str):
        controller = CONTROLLERS.build(controller, config)
    sim = build_simulation(config, terrain)
    sensors = SensorSuite.from_config(config)
    _guarded(controller.start, controller_spec, "start")(sim.standing_targets.copy())
    return Parts(sim, sensors, estimator, controller, estimator_spec, controller_spec)


def _part(given, configured: str, base: type) -> tuple[str, object]:
    """(spec, spec or instance) of a part given as an instance, a spec, or not at all."""
    if given is None:
        return configured, configured
    if isinstance(given, str):
        return given, given
    if not isinstance(given, base):
        raise PluginError(f"{given!r} is not a {base.__module__.split('.')[0]}.{base.__name__}")
    return f"{type(given).__module__}:{type(given).__qualname__}", given


def _guarded(method, spec: str, what: str):
    """`method`, with any exception it raises turned into a one-line PluginFailure."""
    def call(*args):
        try:
            return method(*args)
        except (KeyboardInterrupt, SimulationDiverged, PluginFailure):
            raise
        except Exception as error:
            if is_interrupt(error):     # a Ctrl-C inside a compiled kernel's callback
                raise KeyboardInterrupt from None
            raise PluginFailure(f"'{spec}' failed in {what} at run time: {type(error).__name__}: {error}") from None
    return call


class Onboard:
    """The robot's computer for one tick: the estimator absorbs the new samples, then the
    controller answers joint targets. It never sees ground truth."""

    def __init__(self, parts: Parts):
        self.estimator_update = _guarded(parts.estimator.update, parts.estimator_spec, "update") \
            if parts.estimator is not None else None
        self.estimator = parts.estimator
        self.controller = parts.controller
        self.controller_tick = _guarded(parts.controller.tick, parts.controller_spec, "tick")
        self.controller_spec = parts.controller_spec
        self.builtin = isinstance(parts.controller, Pilot)
        self.latest: Estimate | None = None
        self.joint_targets = parts.sim.standing_targets.copy()

    def tick(self, t: float, samples: list) -> tuple[Command, list[Estimate]]:
        estimates = []
        update = self.estimator_update
        if update is not None:
            for sample in samples_for(self.estimator, samples):
                estimate = update(sample)
                if estimate is not None:
                    if not isinstance(estimate, Estimate):
                        raise PluginFailure(f"estimator returned a {type(estimate).__name__}, not an Estimate")
                    estimates.append(estimate)
            if estimates:
                self.latest = estimates[-1]
        targets = self.controller_tick(t, samples, self.latest)
        if self.builtin:
            return self.controller.last_command, estimates
        if targets is not None:
            self.joint_targets = checked_targets(targets, self.controller_spec)
        details = self.controller.command_details()
        return details if details is not None else joint_command(t, self.joint_targets), estimates


def joint_command(t: float, joint_targets: np.ndarray) -> Command:
    """The Command of a controller that gives joint targets only (gait fields unknown)."""
    return Command(t, np.full(6, np.nan), np.zeros(6, dtype=bool), np.full((6, 3), np.nan), joint_targets,
                   np.zeros(3))


def run(config, recorder: Recorder | None = None, truth_attitude: bool = False,
        estimator: Estimator | str | None = None, controller: Controller | str | None = None,
        terrain: Terrain | str | None = None, parts: Parts | None = None) -> RunOutcome:
    """Simulate `config` for its duration; the metrics come back even when the run stops early.
    `estimator`, `controller` and `terrain` replace the config's (a spec or an instance); `parts`,
    already built by `build_parts`, replaces all of them. `truth_attitude`
    (tests and benchmarks only) feeds the true roll and pitch to the built-in posture loop in
    place of the estimator's."""
    recorder = recorder or NullRecorder()
    parts = parts or build_parts(config, estimator, controller, terrain)
    sim, sensors = parts.sim, parts.sensors
    onboard = Onboard(parts)
    pilot = parts.controller if onboard.builtin else None
    metrics = RunMetrics(config, weight=sim.mass * config.run.gravity, terrain=sim.terrain)
    support = SupportTracker(sim.terrain, config.robot.foot_radius)
    steps = int(round(config.run.duration / config.run.time_step))
    footprint = sim.terrain.footprint()
    arrival = Arrival(config, parts.controller, parts.controller_spec)
    outcome = RunOutcome(metrics={})
    compiling = TimingListener()
    start = time.perf_counter()
    def tick_once():
        """Sensors, estimator, controller and recorder after the simulation reached its current state."""
        truth = sim.truth()
        samples = sensors.update(truth)
        if truth_attitude and pilot is not None:
            pilot.truth_attitude = true_roll_pitch(truth)
        command, estimates = onboard.tick(sim.time, samples)
        tick = make_tick(sim, truth, samples, command, estimates, support)
        metrics.add(tick)
        recorder.record(tick)
        return command

    try:
        recorder.start(config, sim.urdf, sim.terrain)      # in the try: a Ctrl-C meanwhile still closes the file
        start = time.perf_counter()
        with fewer_garbage_collections(), compilation_timer(compiling):
            command = tick_once()       # t = 0: the first samples
            for step in range(steps):
                sim.step(command.joint_targets)
                command = tick_once()
                if step % FALL_CHECK_PERIOD == 0 and beyond_footprint(sim.truth(), footprint):
                    metrics.left_terrain = True
                    outcome.note = left_terrain_note(sim.truth())
                    break
                if sim.body_tilt() > FALL_TILT or (step % FALL_CHECK_PERIOD == 0 and sim.body_touches_ground()):
                    metrics.fell = True
                    break
                if step % FALL_CHECK_PERIOD == 0 and arrival.settled(sim.time):
                    outcome.note = (f"arrived at the target at t = {arrival.time:.3f} s: the run ends "
                                    f"{ARRIVAL_SETTLE:g} s later (gait.end_at_arrival)")
                    break
    except (SimulationDiverged, PluginFailure) as error:
        outcome.error = str(error)
    except (KeyboardInterrupt, SystemError) as error:
        if not is_interrupt(error):
            raise
        outcome.interrupted = True
        outcome.error = f"interrupted at t = {sim.time:.3f} s"
    compile_s = compiling.duration if compiling.done else 0.0
    wall = time.perf_counter() - start - compile_s
    with held_interrupts():     # the run has stopped: a further Ctrl-C must not cut the closing of its file
        outcome.metrics = metrics.summary(sim.time, wall, getattr(parts.controller, "ik_limited_ticks", 0))
        outcome.metrics["compile_s"] = compile_s
        outcome.metrics["arrival_time_s"] = arrival.time
        outcome.metrics["contact_cone_corrections"] = sim.cone_corrections if config.run.contact == "dart" else None
        recorder.finish(outcome.metrics, outcome.error)
    return outcome
