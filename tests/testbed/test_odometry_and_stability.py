"""Leg odometry on known motions of the feet; support polygon and stability margin by hand."""

import numpy as np
import pytest

from testbed.runtime import config
from testbed.model.kinematics import LegGeometry, inverse_kinematics_all, nominal_stance
from testbed.control.odometry import GyroHeading, LegOdometry
from testbed.world.stability import (feet_on_ground, stability_margin, stance_support, support_polygon, support_record,
                                     support_view)

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)


NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
TRIPODS = (np.array([1, 0, 1, 0, 1, 0], bool), np.array([0, 1, 0, 1, 0, 1], bool))


def body_view(world_feet: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """Joint angles that put the feet at `world_feet` for a body at (x, y, yaw)."""
    c, s = np.cos(yaw), np.sin(yaw)
    body_feet = world_feet.copy()
    body_feet[:, 0] = c * (world_feet[:, 0] - x) + s * (world_feet[:, 1] - y)
    body_feet[:, 1] = -s * (world_feet[:, 0] - x) + c * (world_feet[:, 1] - y)
    return inverse_kinematics_all(GEOM, body_feet)


@pytest.mark.parametrize("foot_radius", [0.0, CFG.robot.foot_radius])
def test_odometry_integrates_a_known_planar_motion(foot_radius):
    """Feet fixed in the world, body moving along an arc: odometry recovers the body's path
    (weighing the feet by how much they may have rolled changes nothing when none moves)."""
    neutral = NEUTRAL
    odometry = LegOdometry(GEOM, foot_radius)
    world_feet = neutral.copy()
    stance = np.ones(6, bool)
    x = y = yaw = 0.0
    for k in range(200):   # 1 s at 200 Hz: 2 cm forward, 1 cm left, 3 degrees
        c, s = np.cos(yaw), np.sin(yaw)
        body_feet = world_feet.copy()
        body_feet[:, 0] = c * (world_feet[:, 0] - x) + s * (world_feet[:, 1] - y)
        body_feet[:, 1] = -s * (world_feet[:, 0] - x) + c * (world_feet[:, 1] - y)
        odometry.update(inverse_kinematics_all(GEOM, body_feet), stance)
        x, y, yaw = x + 1e-4, y + 5e-5, yaw + np.radians(3.0) / 200
    assert odometry.x == pytest.approx(x - 1e-4, abs=1e-9)
    assert odometry.y == pytest.approx(y - 5e-5, abs=1e-9)
    assert odometry.yaw == pytest.approx(yaw - np.radians(3.0) / 200, abs=1e-9)


def test_odometry_ignores_dropouts_and_feet_in_the_air():
    odometry = LegOdometry(GEOM)
    q = np.tile([0.0, 0.3, -1.5], 6)
    odometry.update(q, np.ones(6, bool))
    odometry.update(np.full(18, np.nan), np.ones(6, bool))
    moved = q.copy()
    moved[0] += 0.2
    odometry.update(moved, np.zeros(6, bool))          # all feet up: nothing to register
    assert odometry.pose == (0.0, 0.0, 0.0)


def test_support_polygon_and_margin():
    square = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0], [0.0, 0.0]])
    polygon = support_polygon(square)
    assert len(polygon) == 4
    area = 0.5 * np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    assert area == pytest.approx(4.0)                                    # counter-clockwise
    assert stability_margin(polygon, np.array([0.0, 0.0])) == pytest.approx(1.0)
    assert stability_margin(polygon, np.array([0.5, 0.2])) == pytest.approx(0.5)
    assert stability_margin(polygon, np.array([3.0, 0.0])) == pytest.approx(-2.0)
    two = support_polygon(np.array([[0.0, 0.0], [1.0, 0.0]]))
    assert stability_margin(two, np.array([0.5, 0.5])) == pytest.approx(-0.5)
    assert stability_margin(np.empty((0, 2)), np.zeros(2)) == -np.inf


def test_compiled_hull_and_margin_agree_with_the_readable_laws():
    """stability's kernels (_monotone_chain, _margin) against support_polygon and stability_margin:
    zero to six points, with repeated and collinear ones, the centre of mass inside and outside."""
    from testbed.world.stability import _margin, _monotone_chain
    rng = np.random.default_rng(12)
    for case in range(2000):
        points = rng.normal(0.0, 0.2, (rng.integers(0, 7), 2))
        if case % 5 == 0 and len(points) > 2:
            points[1] = points[0]                                   # a repeated foot
        if case % 7 == 0 and len(points) > 2:
            points[2] = 0.5 * (points[0] + points[1])               # three in a line
        com = rng.normal(0.0, 0.2, 2)
        expected = support_polygon(points)
        polygon = _monotone_chain(np.ascontiguousarray(points))
        np.testing.assert_allclose(polygon, expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(_margin(polygon, com[0], com[1]), stability_margin(expected, com),
                                   rtol=1e-12, atol=1e-12)


def test_stance_support_keeps_recent_touches_and_matches_the_separate_functions():
    rng = np.random.default_rng(4)
    support = support_record(0.005, CFG.robot.foot_radius, 0.001)
    last_touch = support_view(support)["last_touch"]
    for step in range(200):
        t = 0.001 * step
        feet, com = rng.normal(0.0, 0.2, (6, 3)), rng.normal(0.0, 0.05, 3)
        contact, resting, swinging = rng.random(6) < 0.4, rng.random(6) < 0.1, rng.random(6) < 0.5
        before = last_touch.copy()
        polygon, margin, late = stance_support(support, t, contact, swinging, feet, com, resting)
        recent = contact | (t - before <= 0.005)
        supporting = recent | resting
        expected = support_polygon(feet[supporting, :2])
        np.testing.assert_allclose(polygon, expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(margin, stability_margin(expected, com[:2]), rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(last_touch, np.where(contact, t, before))
        assert late == sum(1 << leg for leg in range(6) if not (swinging[leg] or recent[leg]))


def test_odometry_rotates_leg_displacements_by_the_given_heading():
    """With a gyro heading of 90 degrees, a step forward in the body frame is a step along +y."""
    neutral = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
    odometry = LegOdometry(GEOM)
    odometry.update(inverse_kinematics_all(GEOM, neutral), np.ones(6, bool), np.pi / 2)
    moved = neutral - [0.01, 0.0, 0.0]         # body 1 cm forward: feet 1 cm back in the body frame
    odometry.update(inverse_kinematics_all(GEOM, moved), np.ones(6, bool), np.pi / 2)
    assert odometry.x == pytest.approx(0.0, abs=1e-12)
    assert odometry.y == pytest.approx(0.01, abs=1e-12)
    assert odometry.yaw == pytest.approx(np.pi / 2)


def test_odometry_bridges_a_tripod_change_over_with_no_foot_down():
    """Body at 0.1 m/s; the tripods swap with 20 ms (four encoder samples) in which no stance foot
    is known: the odometry carries the body on at its measured velocity instead of losing 2 mm."""
    odometry = LegOdometry(GEOM)
    step = 0.1 / 200                                    # m per encoder sample
    start = x = -0.025
    planted = NEUTRAL.copy()
    for k in range(200):                                # 1 s: two half cycles of 0.5 s
        down = TRIPODS[k // 100]
        if k == 100:
            planted[down] += [0.05, 0.0, 0.0]           # the new tripod lands one stride ahead
        world_feet = np.where(down[:, None], planted, NEUTRAL + [x, 0.0, 0.0])   # swinging feet ride along
        stance = down if not 100 <= k < 104 else np.zeros(6, bool)   # the new tripod not yet felt
        odometry.update(body_view(world_feet, x, 0.0, 0.0), stance, 0.0)
        x += step
    assert odometry.x == pytest.approx(x - step - start, abs=1e-6)
    assert odometry.y == pytest.approx(0.0, abs=1e-9)


def test_odometry_needs_one_stance_foot_with_the_gyro_heading():
    """With the gyro's turn between two samples, a single planted foot fixes the body's shift."""
    odometry = LegOdometry(GEOM)
    one = np.zeros(6, bool)
    one[1] = True
    world_feet = NEUTRAL.copy()
    odometry.update(body_view(world_feet, 0.0, 0.0, 0.0), one, 0.0)
    odometry.update(body_view(world_feet, 0.004, -0.002, 0.05), one, 0.05)
    assert odometry.pose == pytest.approx((0.004, -0.002, 0.05), abs=1e-9)


def test_odometry_trusts_the_feet_that_cannot_roll():
    """Walking straight ahead the corner legs' tibias pitch through the stance and the middle legs'
    do not. If the corner feet roll (their centres moving by the foot radius times the pitch
    change, as on a rigid contact), weighing feet by that possible roll leans the odometry on the
    middle feet: its error is 0.38 of the plain mean's (the middle tibias pitch a little too)."""
    radius = CFG.robot.foot_radius
    outward = np.column_stack([np.cos(GEOM.base_angle), np.sin(GEOM.base_angle)])
    plain, weighted = LegOdometry(GEOM), LegOdometry(GEOM, radius)
    stance = np.ones(6, bool)
    planted = NEUTRAL.copy()
    start_pitch = None
    for k in range(100):                                 # 2 cm in 0.5 s
        x = 2e-4 * k
        world_feet = planted.copy()
        for _ in range(3):                               # the roll depends on the pitch it causes
            q = body_view(world_feet, x, 0.0, 0.0).reshape(6, 3)
            pitch = q[:, 1] + q[:, 2]
            start_pitch = pitch if start_pitch is None else start_pitch
            world_feet[:, :2] = planted[:, :2] + radius * (pitch - start_pitch)[:, None] * outward
        for odometry in (plain, weighted):
            odometry.update(q.ravel(), stance, 0.0)
    plain_error, weighted_error = abs(plain.x - x), abs(weighted.x - x)
    assert plain_error > 2e-4                           # a percent of the distance
    assert weighted_error < 0.5 * plain_error


def test_gyro_heading_ignores_turns_of_a_tilted_body():
    """The start-up's path in (roll, pitch): level -> roll -12 deg -> pitch +12 deg (both changing at
    once) -> level, yaw zero throughout. While tilted the body z rate is not the yaw rate: summed
    alone it turns the heading; the integrated rotation does not. A 0.5 deg/s bias, averaged at the
    still start, is removed."""
    from scipy.spatial.transform import Rotation

    dt, bias = 1e-3, np.radians([0.5, -0.5, 0.5])
    heading = GyroHeading(calibration_time=0.2)
    t = 0.0
    for _ in range(200):
        heading.update(t, bias)
        t += dt
    waypoints = np.radians([[0.0, 0.0], [-12.0, 0.0], [0.0, 12.0], [0.0, 0.0]])
    path = np.concatenate([np.linspace(a, b, 200, endpoint=False) for a, b in zip(waypoints, waypoints[1:])]
                          + [waypoints[-1:]])
    attitudes = Rotation.from_euler("ZYX", np.column_stack([np.zeros(len(path)), path[:, 1], path[:, 0]]))
    z_sum, largest = 0.0, 0.0
    for before, after in zip(attitudes[:-1], attitudes[1:]):
        turn = (before.inv() * after).as_rotvec()          # body frame
        heading.update(t, turn / dt + bias)
        z_sum += turn[2]
        largest = max(largest, abs(heading.yaw))
        t += dt
    assert abs(np.degrees(z_sum)) > 1.0            # what summing the z rate alone would say
    assert np.degrees(largest) < 1e-6


def test_gyro_heading_integrates_as_the_rotation_helpers():
    """The compiled integration step against numpy's mounting product, rotate_by_vector and
    euler_from_quaternion's yaw: rates of every size (tiny turns take the small-angle branch)."""
    from scipy.spatial.transform import Rotation

    from testbed.model import spatial as rot
    from testbed.control.odometry import _turn

    rng = np.random.default_rng(0)
    bias = rng.normal(0.0, 0.01, 3)
    mounting = Rotation.from_euler("ZYX", [30.0, -5.0, 170.0], degrees=True).as_matrix()
    for scale in np.repeat([1e-9, 1e-6, 1e-3, 0.1, 1.0, 10.0], 500):
        start = Rotation.random(random_state=rng).as_quat()
        attitude = start.copy()
        gyro = mounting.T @ bias + rng.normal(0.0, scale, 3)
        dt = 1e-3 * (1.0 + rng.random())
        finite, yaw = _turn(attitude, mounting, gyro, bias, dt)
        wx, wy, wz = ((mounting @ gyro - bias) * dt).tolist()
        expected = rot.rotate_by_vector(tuple(start.tolist()), wx, wy, wz)
        assert finite
        np.testing.assert_allclose(attitude, expected, rtol=0, atol=1e-12)
        assert yaw == pytest.approx(rot.euler_from_quaternion(expected)[2], abs=1e-12)
    before = attitude.copy()
    assert _turn(attitude, mounting, np.array([0.0, np.nan, 0.0]), bias, dt) == (False, 0.0)
    np.testing.assert_array_equal(attitude, before)        # a broken sample leaves the attitude alone


def test_support_counts_touching_feet_and_stance_feet_resting_on_the_ground():
    from types import SimpleNamespace
    from testbed.runtime.runner import CONTACT_DEBOUNCE, GROUND_TOLERANCE, SupportTracker
    from testbed.world.terrain import make_terrain
    terrain = make_terrain("flat", CFG, np.random.default_rng(0))
    radius = CFG.robot.foot_radius
    support = SupportTracker(terrain, radius)
    feet = np.column_stack([NEUTRAL[:, :2], np.full(6, radius)])
    feet[1, 2] += 0.5 * GROUND_TOLERANCE        # a stance foot sprung off the ground after an impact
    feet[3, 2] += 0.5 * GROUND_TOLERANCE        # a swing foot just above the ground
    feet[5, 2] += 0.02                          # a stance foot hanging in the air
    touching = np.array([1, 0, 1, 1, 1, 0], bool)     # the swing foot brushes the ground
    stance = np.array([1, 1, 1, 0, 1, 1], bool)

    def polygon(t, contact):
        truth = SimpleNamespace(t=t, foot_contact=contact, foot_positions=feet, com_position=np.zeros(3))
        return support.polygon_and_margin(truth, ~stance)[0]

    assert np.allclose(polygon(0.0, touching), support_polygon(feet[[0, 1, 2, 3, 4], :2]))
    # The swing foot supports for CONTACT_DEBOUNCE after its touch; the stance feet on the ground
    # support without a contact report; the hanging stance foot never does.
    assert np.allclose(polygon(0.5 * CONTACT_DEBOUNCE, np.zeros(6, bool)), support_polygon(feet[[0, 1, 2, 3, 4], :2]))
    assert np.allclose(polygon(2 * CONTACT_DEBOUNCE, np.zeros(6, bool)), support_polygon(feet[[0, 1, 2, 4], :2]))


@pytest.mark.parametrize("name", ["step", "rough"])
def test_support_on_terrain_in_one_call_agrees_with_the_readable_path(name):
    """SupportTracker's one compiled call (late stance feet asked of the terrain inside it) against
    stance_support, the readable Terrain.closest and stance_support again; so does its Python path
    for a terrain with candidate boxes of its own."""
    from types import SimpleNamespace
    from testbed.runtime.runner import CONTACT_DEBOUNCE, GROUND_TOLERANCE, SupportTracker
    from testbed.world.terrain import make_terrain
    from tests.testbed.test_terrain import OwnCandidates
    terrain = make_terrain(name, CFG, np.random.default_rng(2))
    radius = CFG.robot.foot_radius
    support, reference = SupportTracker(terrain, radius), support_record(CONTACT_DEBOUNCE, radius, GROUND_TOLERANCE)
    own = SupportTracker(OwnCandidates.of(make_terrain(name, CFG, np.random.default_rng(2))), radius)
    rng = np.random.default_rng(7)
    asked = 0
    for step in range(600):
        t = 0.001 * step
        feet = np.column_stack([rng.uniform(-0.2, 0.5, (6, 2)), np.zeros(6)])
        ground = np.array([terrain.closest(foot[None])[0][0] for foot in feet])
        feet[:, 2] = radius - ground + rng.choice([0.0, 0.5, 0.99, 1.01, 3.0], 6) * GROUND_TOLERANCE
        com = rng.normal(0.0, 0.05, 3)
        contact, swinging = rng.random(6) < 0.2, rng.random(6) < 0.3
        truth = SimpleNamespace(t=t, foot_contact=contact, foot_positions=feet, com_position=com)
        polygon, margin = support.polygon_and_margin(truth, swinging)
        args = (reference, t, contact, swinging, feet, com)
        expected, expected_margin, late_bits = stance_support(*args, np.zeros(6, bool))
        if late_bits:
            asked += 1
            late = (late_bits >> np.arange(6)) & 1 == 1
            resting = np.zeros(6, dtype=bool)
            resting[late] = feet_on_ground(terrain, feet[late], radius)
            expected, expected_margin, _ = stance_support(*args, resting)
        own_polygon, own_margin = own.polygon_and_margin(truth, swinging)
        for ours in ((polygon, margin), (own_polygon, own_margin)):
            np.testing.assert_allclose(ours[0], expected, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(ours[1], expected_margin, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(support.last_touch, support_view(reference)["last_touch"])
    assert asked > 100


def test_a_better_gyro_bias_replaces_the_start_up_average_and_takes_back_its_heading_error():
    """A still gyro with a z bias of 0.01 rad/s and white noise: the 0.3 s average leaves a bias
    error that turns the heading. An estimate known better (a smaller variance) at 20 s takes its
    place, and the heading turned meanwhile by the old bias's error is taken back; one known worse
    is ignored."""
    rng = np.random.default_rng(2)
    bias, noise, dt = 0.01, 5e-3, 1e-3
    heading = GyroHeading(0.3)
    for k in range(20000):
        heading.update(k * dt, np.array([0.0, 0.0, bias]) + noise * rng.standard_normal(3))
    error = heading.bias[2] - bias
    assert heading.bias_variance == pytest.approx((noise**2) / 300, rel=0.2)
    assert heading.yaw == pytest.approx(-error * (20.0 - 0.3), abs=2e-3)
    assert abs(heading.yaw) > 4e-3
    heading.adopt_bias(20.0, bias + 1.0, heading.bias_variance * 2.0)          # known worse: ignored
    assert heading.bias[2] == pytest.approx(bias + error)
    heading.adopt_bias(20.0, bias, 1e-10)
    assert heading.bias[2] == bias and heading.bias_variance == 1e-10
    assert abs(heading.yaw) < 2e-3
