"""Physics of both contact models: weight carried, friction holds below atan(mu) and not above,
every contact force inside its friction cone, and determinism."""

from functools import lru_cache

import numpy as np
import pytest

from testbed.model.errors import PluginError
from testbed.runtime import config
from testbed.runtime.runner import build_simulation
from testbed.world.contact import CONTACT_MODELS, CompliantContact, DartContact

CONTACTS = ["compliant", "dart"]


@lru_cache(maxsize=None)
def stand(terrain: str, contact: str, duration: float, friction: float | None = None, seed: int = 1):
    """Stand still; return times, body positions, per-foot forces/normals/contact, and the mass."""
    overrides = {"run": {"terrain": terrain, "contact": contact, "seed": seed}}
    if friction is not None:
        overrides["contact"] = {"friction": friction}
    cfg = config.load(overrides=overrides)
    sim = build_simulation(cfg)
    steps = int(round(duration / cfg.run.time_step))
    times, bodies, forces, normals, touching = [], [], [], [], []
    for _ in range(steps):
        sim.step(sim.standing_targets)
        contacts = sim.contacts()
        times.append(sim.time)
        bodies.append(sim.body_transform()[:3, 3].copy())
        forces.append(contacts.forces.copy())
        normals.append(contacts.normals.copy())
        touching.append(contacts.in_contact.copy())
    return (np.array(times), np.array(bodies), np.array(forces), np.array(normals), np.array(touching),
            sim.mass * cfg.run.gravity, cfg.contact.friction, sim)


def normal_and_tangential(forces: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    normal = np.einsum("...i,...i->...", forces, normals)
    tangential = np.linalg.norm(forces - normal[..., None] * normals, axis=-1)
    return normal, tangential


@pytest.mark.parametrize("contact", CONTACTS)
def test_feet_carry_the_weight_on_flat_ground(contact):
    times, _, forces, normals, _, weight, _, _ = stand("flat", contact, 3.0)
    normal, _ = normal_and_tangential(forces, normals)
    last_second = times > 2.0 + 1e-9
    ratio = normal[last_second].sum(axis=1).mean() / weight
    assert ratio == pytest.approx(1.0, abs=0.01)
    # and no foot pulls: a contact only pushes
    assert normal.min() >= 0.0


@pytest.mark.parametrize("contact", CONTACTS)
def test_no_sliding_on_slope_below_friction_angle(contact):
    # 10 degree slope, mu = 0.8: atan(mu) = 38.7 degrees.
    times, bodies, _, _, _, _, _, _ = stand("slope", contact, 2.5)
    settled = np.searchsorted(times, 0.5)
    drift = np.linalg.norm(bodies[settled:, :2] - bodies[settled, :2], axis=1).max()
    assert drift < 1e-3


@pytest.mark.parametrize("contact", CONTACTS)
def test_slides_on_slope_above_friction_angle(contact):
    # mu = 0.1: atan(mu) = 5.7 degrees < 10 degrees; the robot must slide downhill (-x).
    times, bodies, _, _, _, _, _, _ = stand("slope", contact, 2.5, friction=0.1)
    settled = np.searchsorted(times, 0.5)
    assert bodies[-1, 0] - bodies[settled, 0] < -0.05


@pytest.mark.parametrize("contact", CONTACTS)
@pytest.mark.parametrize("case", [("slope", 2.5, None), ("slope", 2.5, 0.1), ("rough", 3.0, None)])
def test_every_contact_force_lies_inside_its_friction_cone(contact, case):
    terrain, duration, friction = case
    _, _, forces, normals, touching, _, mu, _ = stand(terrain, contact, duration, friction)
    normal, tangential = normal_and_tangential(forces, normals)
    assert touching.any()
    assert np.all(tangential[touching] <= mu * normal[touching] * (1 + 1e-9) + 1e-9)
    if friction is not None:   # sliding: the cone is reached, not just respected
        assert np.max(tangential[touching] / np.maximum(normal[touching], 1e-9)) > 0.95 * mu


@pytest.mark.parametrize("terrain", ["flat", "slope"])
def test_dart_cone_projections_only_at_touch_down(terrain):
    """DART's reported forces overshoot the cone while the feet first land; after that, none."""
    cfg = config.load(overrides={"run": {"terrain": terrain, "contact": "dart", "seed": 1}})
    sim = build_simulation(cfg)
    last_correction = 0.0
    for _ in range(2000):
        before = sim.cone_corrections
        sim.step(sim.standing_targets)
        if sim.cone_corrections > before:
            last_correction = sim.time
    assert last_correction < 0.2


@pytest.mark.parametrize("contact", CONTACTS)
def test_same_seed_same_run(contact):
    a = stand("rough", contact, 0.5, seed=11)
    b = stand.__wrapped__("rough", contact, 0.5, seed=11)
    c = stand("rough", contact, 0.5, seed=12)
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
    assert not np.array_equal(a[1], c[1])


def test_ctrl_c_inside_the_compiled_state_read_out_stops_the_run_cleanly(monkeypatch):
    """numba hands a kernel's returned arrays to Python through a callback; a Ctrl-C landing there
    comes out as a SystemError caused by KeyboardInterrupt. The run still ends as interrupted. (The
    compliant contact's state read-out: its first call is at t = 0, its 50th after step 49.)"""
    from testbed.world import contact
    from testbed.runtime.recording import NullRecorder
    from testbed.runtime.runner import run

    kernel, calls = contact._read_out_and_hard_finger, []

    def interrupted_at_the_50th_step(*args):
        calls.append(1)
        if len(calls) == 50:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as interrupt:
                raise SystemError("<function _numba_unpickle> returned a result with an exception set") from interrupt
        return kernel(*args)

    monkeypatch.setattr(contact, "_read_out_and_hard_finger", interrupted_at_the_50th_step)
    finished = []
    recorder = NullRecorder()
    monkeypatch.setattr(recorder, "finish", lambda metrics, error: finished.append(error))
    outcome = run(config.load(overrides={"run": {"duration": 0.2}}), recorder)
    assert outcome.interrupted and outcome.error == "interrupted at t = 0.049 s"
    assert finished == [outcome.error] and outcome.metrics["sim_steps"] == 49


def test_other_system_errors_are_not_taken_for_an_interrupt(monkeypatch):
    from testbed.world import contact
    from testbed.runtime.runner import run

    def broken(*args):
        raise SystemError("something else")

    monkeypatch.setattr(contact, "_read_out_and_hard_finger", broken)
    with pytest.raises(SystemError, match="something else"):
        run(config.load(overrides={"run": {"duration": 0.05}}))


class SlipperyContact(CompliantContact):
    """A contact model from outside the registry's built-ins: the hard finger without friction."""

    def __init__(self, config, terrain):
        super().__init__(config.replace(contact={"friction": 0.0}), terrain)


def test_contact_models_come_from_the_registry():
    assert CONTACT_MODELS.names() == ("compliant", "dart")
    assert CONTACT_MODELS.resolve("compliant") is CompliantContact and CONTACT_MODELS.resolve("dart") is DartContact
    with pytest.raises(PluginError, match="unknown contact model 'glue'"):
        CONTACT_MODELS.check_spec("glue")
    spec = f"{__name__}:SlipperyContact"
    cfg = config.load(overrides={"run": {"terrain": "slope", "contact": spec}})
    sim = build_simulation(cfg)
    assert type(sim.contact) is SlipperyContact
    start = sim.body_transform()[0, 3]
    for _ in range(500):
        sim.step(sim.standing_targets)
    assert sim.body_transform()[0, 3] - start < -0.01            # downhill, with nothing to hold it


def test_swapped_record_arguments_are_an_error():
    """The per-step kernels take records as bytes and view them back by type: bytes of another
    record type do not fit."""
    from testbed.model.kinematics import LegGeometry
    from testbed.world.contact import _read_out_and_hard_finger, compliant_record
    from testbed.world.records import raw
    from testbed.world.stability import stance_support_on_terrain, support_record
    from testbed.world.state import read_out_record
    from testbed.world.terrain import make_terrain
    cfg = config.load()
    for name in ("step", "rough"):
        terrain = make_terrain(name, cfg, np.random.default_rng(0))
        boxes, rule = raw(terrain.boxes.records), raw(terrain.candidate_rule())
        support = support_record(0.005, cfg.robot.foot_radius, 0.001)
        feet, touching = np.zeros((6, 3)), np.zeros(6, bool)
        stance_support_on_terrain(support, 0.0, touching, touching, feet, np.zeros(3), boxes, rule)
        with pytest.raises(ValueError):
            stance_support_on_terrain(support, 0.0, touching, touching, feet, np.zeros(3), rule, boxes)
        with pytest.raises(ValueError):
            stance_support_on_terrain(rule, 0.0, touching, touching, feet, np.zeros(3), boxes, support)
    read_out = raw(read_out_record(cfg.run.time_step, LegGeometry.from_config(cfg.robot)))
    model = raw(compliant_record(cfg.contact, cfg.robot.foot_radius, cfg.run.time_step))
    positions = np.zeros(24)
    _read_out_and_hard_finger(positions, positions, read_out, model, boxes, rule)
    with pytest.raises(ValueError):
        _read_out_and_hard_finger(positions, positions, model, read_out, boxes, rule)
