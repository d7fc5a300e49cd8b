"""The compliant contact's friction spring stretches with the slip of the sphere's material contact
point: a foot that rolls without slipping feels no tangential force, one that spins in place does."""

import numpy as np
import pytest

from testbed.model.kinematics import WorldFeet
from testbed.runtime import config
from testbed.world.contact import ContactArrays, compliant_record, hard_finger, hard_finger_into
from testbed.world.terrain import make_terrain

DEPTH = 0.001           # m the spheres stand in the ground
STEPS = 1000            # 1 s at the default 1 ms step


def setting():
    cfg = config.load(overrides={"run": {"terrain": "flat"}})
    terrain = make_terrain("flat", cfg, np.random.default_rng(0))
    return cfg, terrain, cfg.robot.foot_radius, cfg.run.time_step


def feet_at(centers, velocities, spins):
    rotations = np.repeat(np.eye(3)[None], len(centers), axis=0)
    return WorldFeet(centers, velocities, spins, rotations, centers + np.array([0.0, 0.0, 0.1]))


def start_centers(terrain, radius):
    """Six sphere centres DEPTH into the flat ground, a leg's width apart."""
    xy = np.column_stack([np.linspace(-0.2, 0.2, 6), np.zeros(6)])
    ground = terrain.height(xy)
    return np.column_stack([xy, ground + radius - DEPTH])


def tangential(forces):
    return np.linalg.norm(forces[:, :2], axis=1)


def run_law(cfg, terrain, radius, dt, centers, velocities, spins, steps):
    """hard_finger for `steps` steps on feet moving at `velocities` and spinning at `spins`;
    the tangential forces (steps, 6) and the normal forces."""
    anchors = np.full((6, 3), np.nan)
    out_t, out_n = [], []
    for _ in range(steps):
        feet = feet_at(centers, velocities, spins)
        depth, normals = terrain.sphere_contacts(centers, radius)
        contacts, _ = hard_finger(feet, depth, normals, anchors, cfg.contact, radius, dt)
        out_t.append(contacts.forces - contacts.normal_forces[:, None] * contacts.normals)
        out_n.append(contacts.normal_forces)
        centers = centers + velocities * dt
    return np.array(out_t), np.array(out_n)


def test_a_sphere_rolling_without_slip_feels_no_tangential_force():
    cfg, terrain, radius, dt = setting()
    centers = start_centers(terrain, radius)
    spins = np.tile([0.3, 2.0, 0.5], (6, 1))                    # rad/s, about every axis
    up = np.array([0.0, 0.0, 1.0])
    velocities = np.cross(spins, radius * up)                   # v = w x (r n): no slip
    forces, normal = run_law(cfg, terrain, radius, dt, centers, velocities, spins, STEPS)
    assert normal.min() > 1.0 and np.abs(velocities[:, 0]).max() * STEPS * dt > 0.015   # rolled 2 cm, loaded
    assert np.linalg.norm(forces, axis=2).max() < 1e-6


def test_a_sphere_spinning_in_place_feels_the_spring_against_its_material_slip():
    cfg, terrain, radius, dt = setting()
    centers = start_centers(terrain, radius)
    spin = 2.0                                                  # rad/s about y
    spins = np.tile([0.0, spin, 0.0], (6, 1))
    forces, normal = run_law(cfg, terrain, radius, dt, centers, np.zeros((6, 3)), spins, STEPS)
    slip = np.cross(spins[0], [0.0, 0.0, -radius])              # the material point's velocity, -r w along x
    assert slip[0] < 0.0
    limit = cfg.contact.friction * normal
    # early: the spring's stretch r w t (plus the slip damping), along +x, against the slip
    early = 20
    expected = cfg.contact.tangential_stiffness * radius * spin * early * dt \
        + cfg.contact.tangential_damping * radius * spin
    np.testing.assert_allclose(forces[early - 1, :, 0], np.minimum(expected, limit[early - 1]), rtol=0.1)
    assert np.abs(forces[:, :, 1]).max() < 1e-9
    # late: capped at mu F_n, still against the slip
    np.testing.assert_allclose(forces[-1, :, 0], limit[-1], rtol=1e-9)
    assert (forces[early:, :, 0] > 0.0).all()


def test_kernel_agrees_with_the_readable_law_while_rolling_and_spinning():
    cfg, terrain, radius, dt = setting()
    law = compliant_record(cfg.contact, radius, dt)[0]
    boxes = np.ascontiguousarray(terrain.boxes.records)
    rng = np.random.default_rng(3)
    centers = start_centers(terrain, radius)
    velocities = rng.normal(0.0, 0.02, (6, 3)) * [1, 1, 0.1]
    spins = rng.normal(0.0, 2.0, (6, 3))
    anchors, kernel_anchors = np.full((6, 3), np.nan), np.full((6, 3), np.nan)
    for _ in range(300):
        feet = feet_at(centers, velocities, spins)
        depth, normals = terrain.sphere_contacts(centers, radius)
        expected, local = hard_finger(feet, depth, normals, anchors, cfg.contact, radius, dt)
        out = ContactArrays(*(np.zeros((6, 3)) if i != 1 else np.zeros(6) for i in range(5)))
        candidates = np.ascontiguousarray(terrain.candidates(centers), dtype=np.int64)
        bits = hard_finger_into(feet, law, boxes, candidates, kernel_anchors, out)
        assert bits == sum(1 << leg for leg in range(6) if expected.in_contact[leg])
        np.testing.assert_allclose(out.forces, expected.forces, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(kernel_anchors, anchors, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.local_points, local, rtol=1e-12, atol=1e-12)
        centers = centers + velocities * dt
    assert np.isfinite(anchors).all()
