"""Courses: heights at known points, continuous ramp joints, stairs' rise, seeded rough patches, the
boxes DART collides with agreeing with the analytic height and normal, and every refused course."""

import math

import dartpy as dart
import numpy as np
import pytest

from testbed.model.errors import ConfigError
from testbed.runtime import config
from testbed.world.simulation import build_terrain_skeleton
from testbed.world.terrain import (CourseTerrain, NO_BOX, distances_to_boxes, make_terrain, signed_distance_to_boxes,
                                   sphere_contact_arrays, sphere_contacts)

COURSE = "testbed.world.terrain:CourseTerrain"
TAN12 = math.tan(math.radians(12.0))
SEGMENTS = [{"kind": "flat", "length": 1.0}, {"kind": "ramp", "length": 0.8, "angle_deg": 12.0},
            {"kind": "flat", "length": 0.6}, {"kind": "step", "height": 0.03}, {"kind": "flat", "length": 0.5},
            {"kind": "stairs", "steps": 3, "rise": -0.03, "tread": 0.2},
            {"kind": "rough", "length": 0.6, "amplitude": 0.02, "cell": 0.1},
            {"kind": "ramp", "length": 0.5, "angle_deg": -10.0}]


def course_config(segments=SEGMENTS, **terrain):
    return config.load(overrides={"run": {"terrain": COURSE},
                                  "terrain": {"course": segments, "extent": [-1.0, 4.5, -0.6, 0.6], **terrain}})


def course(seed=1, **terrain) -> CourseTerrain:
    cfg = course_config(**terrain)
    return make_terrain(COURSE, cfg, np.random.default_rng(seed))


def test_heights_at_known_points():
    terrain = course()
    up = 0.8 * TAN12                     # the ramp's climb: 0.1700 m
    # ramp [0.5, 1.3], step at 1.9, stairs [2.4, 3.0], rough [3.0, 3.6], ramp down [3.6, 4.1]
    points = {-0.9: 0.0, 0.4: 0.0, 0.9: 0.4 * TAN12, 1.5: up, 2.0: up + 0.03, 2.5: up, 2.7: up - 0.03,
              2.9: up - 0.06, 3.65: up - 0.06 - 0.05 * math.tan(math.radians(10.0)),
              4.4: up - 0.06 - 0.5 * math.tan(math.radians(10.0))}
    xy = np.array([[x, 0.1] for x in points])
    np.testing.assert_allclose(terrain.height(xy), list(points.values()), atol=1e-12)
    normal = terrain.normal(np.array([[0.9, 0.0], [3.65, 0.0], [1.5, 0.0]]))
    np.testing.assert_allclose(normal, [[-math.sin(math.radians(12)), 0, math.cos(math.radians(12))],
                                        [math.sin(math.radians(10)), 0, math.cos(math.radians(10))], [0, 0, 1]],
                               atol=1e-12)


def test_the_features_crossed_are_the_ramps_ends_the_step_each_riser_and_the_rough_patch():
    """The ramp up's ends (0.5, 1.3), the step (1.9), the stairs' three risers (2.4, 2.6, 2.8), the
    rough patch [3.0, 3.6] and the end of the ramp down (4.1); its start lies on the rough
    patch's end, which the patch's crossing covers."""
    features = course().features()
    assert [f.kind for f in features] == ["edge"] * 6 + ["rough", "edge"]
    np.testing.assert_allclose([f.x0 for f in features], [0.5, 1.3, 1.9, 2.4, 2.6, 2.8, 3.0, 4.1], atol=1e-12)
    assert features[6].x1 == pytest.approx(3.6) and all(f.x0 == f.x1 for f in features if f.kind == "edge")


DOWN = [{"kind": "flat", "length": 1.0}, {"kind": "ramp", "length": 0.5, "angle_deg": -15.0},
        {"kind": "flat", "length": 1.0}]


@pytest.mark.parametrize("segments, joint", [(SEGMENTS, 0.5), (SEGMENTS, 1.3), (SEGMENTS, 4.1), (DOWN, 0.5),
                                             (DOWN, 1.0)])
def test_ramp_joints_are_continuous_in_the_boxes_and_the_analytic_height(segments, joint):
    terrain = course(segments=segments)
    xy = np.array([[joint - 1e-7, 0.05], [joint + 1e-7, 0.05]])
    heights = terrain.height(xy)
    assert heights[1] - heights[0] == pytest.approx(0.0, abs=1e-6)
    # The union of boxes has its top there too, and is solid below it: just above the surface is
    # outside, anywhere down to 5 cm below it inside.
    above = np.column_stack([xy, heights + 1e-5])
    assert (terrain.closest(above)[0] > 0).all()
    for depth in (1e-5, 1e-3, 0.01, 0.05):
        for dx in (-0.01, -1e-4, 1e-4, 0.01):
            point = np.array([[joint + dx, 0.05, terrain.height(np.array([[joint + dx, 0.05]]))[0] - depth]])
            assert terrain.closest(point)[0][0] < 0


def test_stairs_rise_by_steps_times_rise():
    stairs = [{"kind": "flat", "length": 0.6}, {"kind": "stairs", "steps": 4, "rise": 0.035, "tread": 0.18},
              {"kind": "flat", "length": 0.5}]
    terrain = course(segments=stairs)
    before, after = terrain.height(np.array([[0.05, 0.0], [0.1 + 4 * 0.18 + 0.2, 0.0]]))
    assert after - before == pytest.approx(4 * 0.035, abs=1e-12)
    treads = terrain.height(np.array([[0.1 + 0.18 * (k + 0.5), 0.0] for k in range(4)]))
    np.testing.assert_allclose(np.diff(treads), 0.035, atol=1e-12)


def test_rough_patches_are_seeded_bounded_and_differ_between_seeds():
    a, b, c = course(seed=5), course(seed=5), course(seed=6)
    rough = lambda terrain: next(piece for piece in terrain.pieces if piece.kind == "rough").tops
    np.testing.assert_array_equal(rough(a), rough(b))
    assert not np.array_equal(rough(a), rough(c))
    level = 0.8 * TAN12 + 0.03 - 0.09
    assert np.abs(rough(a) - level).max() <= 0.02 and np.abs(rough(a) - level).max() > 0.015
    assert rough(a).shape == (6, 12)


def test_the_run_seed_drives_the_rough_patches():
    from testbed.runtime.runner import build_simulation
    tops = [next(piece for piece in build_simulation(course_config().replace(run={"seed": seed})).terrain.pieces
                 if piece.kind == "rough").tops for seed in (3, 3, 4)]
    np.testing.assert_array_equal(tops[0], tops[1])
    assert not np.array_equal(tops[0], tops[2])


def dart_raycast_down(group, x: float, y: float) -> tuple[float, np.ndarray]:
    result = dart.collision.RaycastResult()
    assert group.raycast([x, y, 1.0], [x, y, -1.0], dart.collision.RaycastOption(), result)
    hit = result.mRayHits[0]
    return float(hit.mPoint[2]), np.asarray(hit.mNormal)


def test_height_and_normal_agree_with_the_dart_shapes():
    terrain = course(seed=2)
    detector = dart.collision.BulletCollisionDetector()
    group = detector.createCollisionGroup()
    skeleton = build_terrain_skeleton(terrain, 0.8)     # keep alive: the group does not own it
    group.addShapeFramesOf(skeleton)
    edges = np.concatenate([terrain.starts, [4.5], 3.0 + 0.1 * np.arange(7)])   # pieces' and blocks' edges
    rng = np.random.default_rng(4)
    checked = 0
    for x, y in rng.uniform([-0.95, -0.55], [4.45, 0.55], (300, 2)):
        if np.abs(x - edges).min() < 0.005 or np.abs(y - (-0.6 + 0.1 * np.round((y + 0.6) / 0.1))) < 0.005:
            continue
        z, normal = dart_raycast_down(group, x, y)
        assert terrain.height(np.array([[x, y]]))[0] == pytest.approx(z, abs=1e-6)
        np.testing.assert_allclose(terrain.normal(np.array([[x, y]]))[0], normal, atol=1e-6)
        checked += 1
    assert checked > 200


def test_binned_candidates_find_what_every_box_finds():
    terrain = course(seed=3)
    assert terrain.candidate_rule() is None          # rough patches: candidates from the bins
    rng = np.random.default_rng(8)
    xy = rng.uniform([-1.0, -0.6], [4.5, 0.6], (2000, 2))
    xy[:300, 0] = 3.0 + rng.uniform(-0.05, 0.65, 300)          # over the rough patch
    points = np.column_stack([xy, terrain.height(xy) + rng.uniform(-0.01, 0.02, len(xy))])
    every = np.broadcast_to(np.arange(len(terrain.boxes)), (len(points), len(terrain.boxes)))
    np.testing.assert_allclose(terrain.closest(points)[0], signed_distance_to_boxes(points, terrain.boxes, every)[0],
                               atol=1e-12)
    radius = 0.01
    depth, normal = terrain.sphere_contacts(points, radius)
    expected_depth, expected_normal = sphere_contacts(points, radius, terrain.boxes, every)
    np.testing.assert_allclose(depth, expected_depth, atol=1e-12)
    np.testing.assert_allclose(normal, expected_normal, atol=1e-12)
    candidates = np.ascontiguousarray(terrain.candidates(points))
    assert (candidates == NO_BOX).any()
    compiled_depth, compiled_normal = sphere_contact_arrays(points, radius, terrain.boxes.records, candidates)
    np.testing.assert_allclose(compiled_depth, depth, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(compiled_normal, normal, rtol=1e-12, atol=1e-12)
    assert 200 < (depth > 0).sum() < 1800


def test_the_compiled_bin_lookup_gives_the_readable_ones_rows_on_and_off_the_table():
    bins = course(seed=3)._bins
    rng = np.random.default_rng(4)
    points = rng.uniform([-3.0, -2.0, 0.0], [7.0, 2.0, 0.1], (3000, 3))       # the table spans [-1, 4.5] x [-0.6, 0.6]
    points[:3, :2] = [[bins.x0, bins.y0], [bins.x0 + bins.size, bins.y0 - 1e-9], [bins.x0 - 1e-9, bins.y0 + 1.0]]
    np.testing.assert_array_equal(bins.near(points), bins.near_readable(points))
    assert (bins.near(points) != NO_BOX).any(axis=1).all()


def test_the_support_check_finds_late_feet_resting_among_binned_candidates():
    from testbed.runtime.runner import GROUND_TOLERANCE
    from testbed.world.records import raw
    from testbed.world.stability import resting_feet, support_record
    terrain, radius = course(seed=3), 0.01
    rng = np.random.default_rng(5)
    xy = np.column_stack([rng.uniform(2.9, 3.7, 6), rng.uniform(-0.2, 0.2, 6)])     # over the rough patch
    clearance = np.array([-0.002, 0.0, 0.0005, 0.0015, 0.01, 0.0009])               # m, the sphere above its ground
    feet = np.column_stack([xy, np.zeros(6)])
    for _ in range(30):     # the height under a foot's centre is not its sphere's ground near a block's edge: iterate
        feet[:, 2] += radius + clearance - terrain.closest(feet)[0]
    late = 0b101111                                                                  # leg 4 is not asked
    candidates = np.ascontiguousarray(terrain.candidates(feet), dtype=np.int64)
    resting = resting_feet(support_record(0.005, radius, GROUND_TOLERANCE), feet, late, raw(terrain.boxes.records),
                           candidates)
    np.testing.assert_array_equal(resting, [True, True, True, False, False, True])


def test_no_box_candidates_count_as_absent():
    terrain = course(seed=3)
    points = np.array([[0.0, 0.0, 0.005], [2.0, 0.0, 0.19]])
    candidates = np.ascontiguousarray(terrain.candidates(points))
    padded = np.concatenate([np.full((2, 3), NO_BOX), candidates], axis=1)
    np.testing.assert_array_equal(distances_to_boxes(points, terrain.boxes, padded)[0][:, :3], np.inf)
    np.testing.assert_allclose(signed_distance_to_boxes(points, terrain.boxes, padded)[0],
                               terrain.closest(points)[0], atol=1e-15)


def test_a_course_without_rough_patches_is_followed_by_compiled_code():
    terrain = course(segments=SEGMENTS[:6])
    assert terrain.candidate_rule() is not None
    assert len(terrain.boxes) == 10         # 7 level pieces, the ramp and its fill


def test_last_level_continues_to_the_extent_and_the_footprint_is_the_extent():
    terrain = course(segments=[{"kind": "step", "height": 0.02}, {"kind": "flat", "length": 0.3}])
    assert terrain.height(np.array([[4.4, 0.5]]))[0] == pytest.approx(0.02)
    assert terrain.footprint() == pytest.approx((-1.0, 4.5, -0.6, 0.6))


@pytest.mark.parametrize("terrain, message", [
    ({"course": []}, "terrain.course is empty"),
    ({"course": [{"kind": "hill", "length": 1.0}]}, r"course\[0\]: unknown kind 'hill'"),
    ({"course": [{"kind": "flat"}]}, r"course\[0\] \(flat\) length must be a positive"),
    ({"course": [{"kind": "flat", "length": -1.0}]}, r"course\[0\] \(flat\) length"),
    ({"course": [{"kind": "step", "height": 0.03, "length": 1.0}]}, r"\(step\) takes height, not length"),
    ({"course": [{"kind": "flat", "length": 1.0, "slope": 3}]}, r"unknown config key 'terrain.course\[0\].slope'"),
    ({"course": [{"kind": "ramp", "length": 1.0, "angle_deg": 60.0}]}, "angle_deg must be non-zero and within"),
    ({"course": [{"kind": "ramp", "length": 1.0}]}, "angle_deg must be non-zero"),
    ({"course": [{"kind": "step", "height": 0.0}]}, "height must be non-zero"),
    ({"course": [{"kind": "stairs", "steps": 0, "rise": 0.02, "tread": 0.2}]}, r"steps must lie in \[1, 100\]"),
    ({"course": [{"kind": "stairs", "steps": 2.5, "rise": 0.02, "tread": 0.2}]}, "must be an integer"),
    ({"course": [{"kind": "stairs", "steps": 2, "rise": 0.02, "tread": 0.0}]}, "tread must be a positive"),
    ({"course": [{"kind": "rough", "length": 1.0, "amplitude": 0.02, "cell": 0.01}]}, r"cell must lie in \[0.02"),
    ({"course": [{"kind": "rough", "length": 1.0, "amplitude": 0.0, "cell": 0.1}]}, "amplitude must lie in"),
    ({"course": [{"kind": "flat", "length": float("nan")}]}, "must be finite"),
    ({"course": [{"kind": "flat", "length": 9.0}]}, r"ends at x = 8.500 m, beyond terrain.extent's x_max 6"),
    ({"course": [{"kind": "flat", "length": 1.0}], "course_start": -3.0}, "course_start -3.0 m lies outside"),
    ({"course": [{"kind": "step", "height": 0.08}]}, r"8.0 cm rise is more than the legs can clear"),
    ({"course": [{"kind": "stairs", "steps": 2, "rise": -0.09, "tread": 0.2}]}, r"9.0 cm drop is more than"),
    ({"course": [{"kind": "stairs", "steps": 2, "rise": 0.02, "tread": 0.015}]},
     "tread 0.015 m is narrower than the foot"),
    ({"course": [{"kind": "rough", "length": 1.0, "amplitude": 0.06, "cell": 0.1}]}, "amplitude 6.0 cm is more than"),
    ({"course": [{"kind": "rough", "length": 6.0, "amplitude": 0.02, "cell": 0.02}]}, "more than 20000"),
    ({"course": {"kind": "flat"}}, "must be a list"),
])
def test_bad_courses_are_refused_when_the_config_loads(terrain, message):
    with pytest.raises(ConfigError, match=message):
        config.load(overrides={"run": {"terrain": "course"}, "terrain": terrain})


def test_a_course_spec_is_checked_when_the_terrain_is_built():
    cfg = config.load(overrides={"run": {"terrain": COURSE}, "terrain": {"course": []}})
    with pytest.raises(ConfigError, match="terrain.course is empty"):
        make_terrain(COURSE, cfg, np.random.default_rng(0))


def test_a_rough_cell_smaller_than_the_foot_is_refused():
    with pytest.raises(ConfigError, match="cell 0.03 m is smaller than the foot"):
        config.load(overrides={"run": {"terrain": "course"}, "robot": {"foot_radius": 0.02},
                               "terrain": {"course": [{"kind": "rough", "length": 1.0, "amplitude": 0.02,
                                                       "cell": 0.03}]}})


def test_the_registry_names_the_new_terrains():
    from testbed.world.terrain import TERRAINS
    assert {"course", "heightmap"} <= set(TERRAINS.names())


def test_the_example_course_loads_and_climbs_as_documented():
    from pathlib import Path
    cfg = config.load(Path(__file__).parents[2] / "examples" / "course.toml")
    terrain = make_terrain("course", cfg, np.random.default_rng(0))
    assert cfg.terrain.course_end == pytest.approx(7.3)
    # 12 degrees up over 0.8 m, a 3 cm step up, 3 stairs of 3 cm down, 10 degrees down over 0.8 m
    end = 0.8 * TAN12 + 0.03 - 0.09 - 0.8 * math.tan(math.radians(10.0))
    np.testing.assert_allclose(terrain.height(np.array([[7.95, 0.0], [6.5, 1.0]])), end, atol=1e-12)
