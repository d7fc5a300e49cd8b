"""The run loop: one scenario from config to metrics.

One tick per physics step: simulation, then (as later issues add them) sensors, estimator,
controller, gait/IK, joint commands; the recorder sits beside it. Ground truth goes only to the
metrics and the recorder.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from testbed.config import Config
from testbed.errors import SimulationDiverged
from testbed.metrics import StandMetrics
from testbed.simulation import Simulation
from testbed.terrain import TERRAIN_STREAM, make_terrain

FALL_CHECK_PERIOD = 10   # physics steps between ground-touch checks of the body


@dataclass
class RunOutcome:
    metrics: dict
    error: str | None = None        # set when the run stopped early (divergence, interrupt)
    interrupted: bool = False
    extra: dict = field(default_factory=dict)


def seed_sequence(config: Config) -> np.random.SeedSequence:
    return np.random.SeedSequence(config.run.seed)


def build_simulation(config: Config) -> Simulation:
    streams = seed_sequence(config).spawn(TERRAIN_STREAM + 1)
    terrain = make_terrain(config.run.terrain, config.terrain, np.random.default_rng(streams[TERRAIN_STREAM]))
    return Simulation(config, terrain)


def run(config: Config) -> RunOutcome:
    """Simulate `config` for its duration; returns the metrics even when stopped early."""
    sim = build_simulation(config)
    steps = int(round(config.run.duration / config.run.time_step))
    metrics = StandMetrics(weight=sim.mass * config.run.gravity, time_step=config.run.time_step,
                           duration=config.run.duration)
    targets = sim.standing_targets
    outcome = RunOutcome(metrics={})
    start = time.perf_counter()
    try:
        for step in range(steps):
            sim.step(targets)
            metrics.add_contacts(sim.time, sim.contacts())
            if sim.body_tilt() > np.radians(45.0) or (step % FALL_CHECK_PERIOD == 0 and sim.body_touches_ground()):
                metrics.fell = True
                break
    except SimulationDiverged as error:
        outcome.error = str(error)
    except KeyboardInterrupt:
        outcome.interrupted = True
        outcome.error = f"interrupted at t = {sim.time:.3f} s"
    wall = time.perf_counter() - start
    outcome.metrics = metrics.summary(sim_time=sim.time, wall_s=wall, sim_steps=int(round(sim.time / config.run.time_step)))
    outcome.metrics["contact_cone_corrections"] = sim.cone_corrections if config.run.contact == "dart" else None
    return outcome
