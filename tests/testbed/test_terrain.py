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


@pytest.mark.parametrize("name", ["flat", "slope", "step", "course"])
def test_a_long_extent_is_accepted_where_no_blocks_are_built(name):
    long = {"extent": [-2.0, 64.0, -3.0, 3.0], "course": [{"kind": "flat", "length": 1.0}]}
    cfg = config.load(overrides={"run": {"terrain": name}, "terrain": long})
    assert make_terrain(name, cfg, np.random.default_rng(0)).footprint()[1] >= 64.0


def test_rough_ground_refuses_more_blocks_than_it_can_build():
    with pytest.raises(ConfigError, match=r"terrain.extent / rough_cell gives \d+ blocks, more than 20000"):
        config.load(overrides={"run": {"terrain": "rough"},
                               "terrain": {"extent": [-2.0, 64.0, -3.0, 3.0], "rough_cell": 0.02}})


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
    rule = terrain.candidate_rule()
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(-2.5, 2.5, (300, 2)), rng.uniform(-0.06, 0.06, 300)])
    points[:20, 0] = CFG.terrain.step_edge_x + rng.normal(0.0, 1e-3, 20)      # at the step's riser
    points[20:40, :2] = np.round(points[20:40, :2] / CFG.terrain.rough_cell) * CFG.terrain.rough_cell  # block edges
    candidates = candidates_by_rule(points, rule)
    np.testing.assert_array_equal(candidates, terrain.candidates(points))
    distances = [closest_distance(point, terrain.boxes.records, row) for point, row in zip(points, candidates)]
    np.testing.assert_allclose(distances, terrain.closest(points)[0], rtol=1e-12, atol=1e-12)
    assert OwnCandidates.of(terrain).candidate_rule() is None


def random_boxes(rng: np.random.Generator, count: int):
    """Axis-aligned boxes, then rotated ones, with points inside, outside, near and (axis-aligned
    only, where no rounding can pick another face) on their faces, edges and corners."""
    from scipy.spatial.transform import Rotation
    from testbed.world.terrain import Boxes
    rotations = np.concatenate([np.broadcast_to(np.eye(3), (count, 3, 3)),
                                Rotation.random(count, random_state=7).as_matrix()])
    centers, halves = rng.normal(0.0, 0.2, (2 * count, 3)), rng.uniform(0.01, 0.3, (2 * count, 3))
    points = []
    for index, (center, half, rotation) in enumerate(zip(centers, halves, rotations)):
        scales = (0.5, 0.999, 1.0, 1.001, 2.0) if index < count else (0.5, 0.999, 1.001, 2.0)
        for scale in scales:
            signs = rng.choice([-1.0, 1.0], 3)
            points.append(center + rotation @ (half * signs * np.where(rng.random(3) < 0.5, scale, rng.random(3))))
    return Boxes(centers, halves, rotations), np.array(points)


def test_compiled_box_distances_agree_with_the_numpy_law():
    from testbed.world.terrain import box_distances, distances_to_boxes
    boxes, points = random_boxes(np.random.default_rng(6), 100)
    candidates = np.tile(np.arange(len(boxes)), (len(points), 1))
    expected_distance, expected_normal = distances_to_boxes(points, boxes, candidates)
    distance, normal = box_distances(points, boxes.records, candidates)
    np.testing.assert_allclose(distance, expected_distance, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(normal, expected_normal, rtol=1e-12, atol=1e-12)
    assert (expected_distance < 0.0).any() and (expected_distance > 0.0).any()


@pytest.mark.parametrize("name", ["step", "rough"])
def test_compiled_sphere_contacts_agree_with_the_numpy_law(name):
    from testbed.world.terrain import sphere_contact_arrays
    terrain = make_terrain(name, CFG, np.random.default_rng(3))
    rng = np.random.default_rng(9)
    radius = CFG.robot.foot_radius
    xy = rng.uniform(-1.5, 1.5, (500, 2))
    xy[:100, 0] = CFG.terrain.step_edge_x + rng.normal(0.0, radius, 100)   # against the riser
    centers = np.column_stack([xy, terrain.height(xy) + rng.uniform(-radius, 2 * radius, len(xy))])
    depth, normal = terrain.sphere_contacts(centers, radius)
    candidates = np.ascontiguousarray(terrain.candidates(centers), dtype=np.int64)
    compiled_depth, compiled_normal = sphere_contact_arrays(centers, radius, terrain.boxes.records, candidates)
    np.testing.assert_allclose(compiled_depth, depth, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(compiled_normal, normal, rtol=1e-12, atol=1e-12)
    assert 50 < (depth > 0.0).sum() < 450
