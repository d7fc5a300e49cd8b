"""Analytic terrain queries agree with the DART shapes that represent each terrain."""

import dartpy as dart
import numpy as np
import pytest

from testbed.runtime import config
from testbed.model.errors import ConfigError
from testbed.world.simulation import build_terrain_skeleton
from testbed.world.terrain import make_terrain

CFG = config.load()


def dart_raycast_down(group, x: float, y: float) -> tuple[float, np.ndarray]:
    result = dart.collision.RaycastResult()
    assert group.raycast([x, y, 1.0], [x, y, -1.0], dart.collision.RaycastOption(), result)
    hit = result.mRayHits[0]
    return float(hit.mPoint[2]), np.asarray(hit.mNormal)


# A smaller terrain keeps Bullet's raycast set-up short (600 rough blocks instead of 4800).
SMALL = config.load(overrides={"terrain": {"extent": [-1.5, 1.5, -1.0, 1.0]}})


@pytest.mark.parametrize("name", ["flat", "slope", "step", "rough"])
def test_height_and_normal_agree_with_dart_shapes(name):
    terrain = make_terrain(name, SMALL, np.random.default_rng(3))
    detector = dart.collision.BulletCollisionDetector()   # the detector with raycasts in DART
    group = detector.createCollisionGroup()
    skeleton = build_terrain_skeleton(terrain, 0.8)   # keep alive: the group does not own it
    group.addShapeFramesOf(skeleton)
    rng = np.random.default_rng(4)
    cell = CFG.terrain.rough_cell
    for x, y in rng.uniform([-1.4, -0.9], [1.4, 0.9], (40, 2)):
        if name == "rough":   # stay off block edges, where the normal is not defined
            x, y = (np.floor(np.array([x, y]) / cell) + 0.5) * cell
        if name == "step" and abs(x - CFG.terrain.step_edge_x) < 0.01:
            continue
        z, normal = dart_raycast_down(group, x, y)
        assert terrain.height(np.array([[x, y]]))[0] == pytest.approx(z, abs=1e-6)
        assert np.allclose(terrain.normal(np.array([[x, y]]))[0], normal, atol=1e-6)


@pytest.mark.parametrize("name", ["flat", "slope", "step", "rough"])
def test_closest_point_query_matches_height_above_surface(name):
    terrain = make_terrain(name, CFG, np.random.default_rng(5))
    rng = np.random.default_rng(6)
    cell = CFG.terrain.rough_cell
    xy = (np.floor(rng.uniform([-1, -2], [5, 2], (30, 2)) / cell) + 0.5) * cell
    xy = xy[np.abs(xy[:, 0] - CFG.terrain.step_edge_x) > 0.05]
    normals = terrain.normal(xy)
    for lift in (0.004, -0.002):
        points = np.column_stack([xy, terrain.height(xy)]) + lift * normals
        distance, normal = terrain.closest(points)
        assert np.allclose(distance, lift, atol=1e-9)
        assert np.allclose(normal, normals, atol=1e-9)


def test_step_riser_pushes_sideways():
    up_step = config.load(overrides={"terrain": {"step_height": 0.04}})
    terrain = make_terrain("step", up_step, np.random.default_rng(0))
    edge = CFG.terrain.step_edge_x
    distance, normal = terrain.closest(np.array([[edge - 0.005, 0.0, 0.02]]))
    assert distance[0] == pytest.approx(0.005)
    assert np.allclose(normal[0], [-1.0, 0.0, 0.0])


def test_rough_terrain_is_seeded_and_bounded():
    a = make_terrain("rough", CFG, np.random.default_rng(7))
    b = make_terrain("rough", CFG, np.random.default_rng(7))
    c = make_terrain("rough", CFG, np.random.default_rng(8))
    assert np.array_equal(a.tops, b.tops)
    assert not np.array_equal(a.tops, c.tops)
    assert np.abs(a.tops).max() <= CFG.terrain.rough_amplitude
    assert a.tops.std() == pytest.approx(CFG.terrain.rough_amplitude / np.sqrt(3), rel=0.05)


def test_step_edge_outside_extent_is_rejected():
    bad = config.load(overrides={"terrain": {"step_edge_x": 100.0}})
    with pytest.raises(ConfigError, match="step_edge_x"):
        make_terrain("step", bad, np.random.default_rng(0))


class OwnCandidates:
    """A terrain whose candidate boxes come from a method of its own (Terrain.candidate_rule: None)."""

    @staticmethod
    def of(terrain):
        kind = type(terrain)
        subclass = type(f"Own{kind.__name__}", (kind,), {"candidates": lambda self, points: kind.candidates(self, points)})
        terrain.__class__ = subclass
        return terrain


@pytest.mark.parametrize("name", ["flat", "slope", "step", "rough"])
def test_candidate_rules_give_the_terrains_candidates_and_closest_distances(name):
    from testbed.world.terrain import candidates_by_rule, closest_distance
    terrain = make_terrain(name, CFG, np.random.default_rng(3))
    rule, data = terrain.candidate_rule()
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(-2.5, 2.5, (300, 2)), rng.uniform(-0.06, 0.06, 300)])
    points[:20, 0] = CFG.terrain.step_edge_x + rng.normal(0.0, 1e-3, 20)      # at the step's riser
    points[20:40, :2] = np.round(points[20:40, :2] / CFG.terrain.rough_cell) * CFG.terrain.rough_cell  # block edges
    candidates = candidates_by_rule(points, rule, data)
    np.testing.assert_array_equal(candidates, terrain.candidates(points))
    boxes = terrain.boxes
    distances = [closest_distance(point, boxes.centers, boxes.half_extents, boxes.rotations, row)
                 for point, row in zip(points, candidates)]
    expected = terrain.closest(points)[0]
    assert np.array_equal(np.array(distances).view(np.uint64), expected.view(np.uint64))
    assert OwnCandidates.of(terrain).candidate_rule() is None


def test_box_distance_on_scalars_equals_its_array_version_bit_for_bit():
    """terrain._box_distance against the version on (3,) arrays it replaced (below, as it was), over
    points inside, outside, on faces and edges of rotated and axis-aligned boxes."""
    import math
    from numba import njit
    from scipy.spatial.transform import Rotation
    from testbed.world.terrain import _box_distance

    @njit
    def on_arrays(point, center, half, rotation, normal):
        local, excess = np.empty(3), np.empty(3)
        outside_sq, face = 0.0, 0
        for i in range(3):
            local[i] = (rotation[0, i] * (point[0] - center[0]) + rotation[1, i] * (point[1] - center[1])
                        + rotation[2, i] * (point[2] - center[2]))
            excess[i] = abs(local[i]) - half[i]
            if excess[i] > 0.0:
                outside_sq += excess[i] * excess[i]
            if excess[i] > excess[face]:
                face = i
        outside_norm = math.sqrt(outside_sq)
        normal_local = np.zeros(3)
        if outside_norm > 1e-12:
            for i in range(3):
                normal_local[i] = max(excess[i], 0.0) * np.sign(local[i]) / outside_norm
        else:
            normal_local[face] = 1.0 if local[face] >= 0.0 else -1.0
        for i in range(3):
            normal[i] = rotation[i, 0] * normal_local[0] + rotation[i, 1] * normal_local[1] + rotation[i, 2] * normal_local[2]
        return outside_norm + min(excess[face], 0.0)

    rng = np.random.default_rng(6)
    rotations = np.concatenate([np.broadcast_to(np.eye(3), (100, 3, 3)), Rotation.random(100, random_state=7).as_matrix()])
    for rotation in rotations:
        center, half = rng.normal(0.0, 0.2, 3), rng.uniform(0.01, 0.3, 3)
        for scale in (0.5, 0.999, 1.0, 1.001, 2.0):
            point = center + rotation @ (half * rng.choice([-1.0, 1.0], 3) * np.where(rng.random(3) < 0.5, scale, rng.random(3)))
            ours, theirs = np.empty(3), np.empty(3)
            distance = _box_distance(point, center, half, rotation, ours)
            expected = on_arrays(point, center, half, rotation, theirs)
            assert np.array_equal(np.array([distance]).view(np.uint64), np.array([expected]).view(np.uint64))
            assert np.array_equal(ours.view(np.uint64), theirs.view(np.uint64))
