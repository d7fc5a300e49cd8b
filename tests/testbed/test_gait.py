"""Gait timing against the gait table, the stance line and the elliptic swing of the paper."""

import dataclasses

import numpy as np
import pytest

from testbed.runtime import config
from testbed.control.gait import (FOOTHOLD_MARGIN, FOOTHOLD_REACH, FOOTHOLDS, GAITS, STANCE_SETTLE_TIME, GaitGenerator, GaitPattern, TerrainAdaptation, Twist,
                                  footholds_slope, walk_plane)
from testbed.model.kinematics import LegGeometry, nominal_stance

CFG = config.load()
GEOM = LegGeometry.from_config(CFG.robot)
NEUTRAL = nominal_stance(GEOM, CFG.robot.stance_radius, CFG.robot.stance_height, CFG.robot.foot_radius)
DT = 0.001
NO_LEG = np.zeros(6, dtype=bool)     # step_on_floor: every sensor reads its ground
# Neighbours around the body (legs numbered counter-clockwise, 0-based here).
ADJACENT = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0)]


def swing_schedule(name: str, cycles: int = 3, period: float = 1.2) -> tuple[np.ndarray, np.ndarray]:
    gait = GaitGenerator(name, NEUTRAL, period, 0.03)
    t = np.arange(1, int(cycles * period / DT) + 1) * DT
    return t, np.array([gait.scheduled_swing(ti) for ti in t])


@pytest.mark.parametrize("name, duty", [("tripod", 1 / 2), ("ripple", 2 / 3), ("wave", 5 / 6)])
def test_duty_factor_of_every_leg_matches_the_table(name, duty):
    _, swing = swing_schedule(name)
    assert GAITS.resolve(name).duty == pytest.approx(duty)
    assert np.allclose(1.0 - swing.mean(axis=0), duty, atol=2e-3)


@pytest.mark.parametrize("name", ["tripod", "ripple", "wave"])
def test_swing_starts_at_the_tabled_phase_offsets(name):
    period = 1.2
    t, swing = swing_schedule(name, period=period)
    starts = t[1:][np.diff(swing.astype(int), axis=0).T[0] == 1]   # leg 1's swing starts
    for leg in range(6):
        leg_starts = t[1:][np.diff(swing[:, leg].astype(int)) == 1]
        offsets = np.mod(leg_starts / period, 1.0)
        assert np.allclose(offsets, GAITS.resolve(name).swing_start[leg], atol=2e-3) or \
            np.allclose(np.mod(offsets - GAITS.resolve(name).swing_start[leg] + 0.5, 1.0) - 0.5, 0.0, atol=2e-3)
    assert len(starts) >= 2


def test_tripod_alternates_135_and_246_and_no_neighbours_swing_together():
    _, swing = swing_schedule("tripod")
    assert np.array_equal(swing[:, 0], swing[:, 2]) and np.array_equal(swing[:, 0], swing[:, 4])
    assert np.array_equal(swing[:, 1], swing[:, 3]) and np.array_equal(swing[:, 1], swing[:, 5])
    assert not np.any(swing[:, 0] & swing[:, 1])
    for a, b in ADJACENT:
        assert not np.any(swing[:, a] & swing[:, b])


@pytest.mark.parametrize("name, most", [("ripple", 2), ("wave", 1)])
def test_ripple_and_wave_lift_at_most_their_share_of_legs(name, most):
    _, swing = swing_schedule(name)
    assert swing.sum(axis=1).max() == most
    for a, b in ADJACENT:
        assert not np.any(swing[:, a] & swing[:, b])


def test_stance_is_a_straight_line_of_one_step_and_swing_an_ellipse():
    speed, period, height = 0.1, 1.0, 0.03
    gait = GaitGenerator("tripod", NEUTRAL, period, height)
    gait.state.feet[:] = NEUTRAL
    command = Twist(vx=speed)
    feet, swinging = [], []
    for k in range(1, 3001):
        feet.append(gait.step(k * DT, DT, command))
        swinging.append(gait.state.swinging.copy())
    feet, swinging = np.array(feet)[1000:], np.array(swinging)[1000:]   # past the first cycle
    leg = 0
    stance = ~swinging[:, leg]
    # one stance: consecutive stance samples of leg 1
    runs = np.split(np.arange(len(stance)), np.flatnonzero(np.diff(stance.astype(int))) + 1)
    stance_run = next(r for r in runs if stance[r[0]] and len(r) > 400)
    path = feet[stance_run, leg]
    step = speed * 0.5 * period
    assert path[0, 0] - path[-1, 0] == pytest.approx(step, rel=0.01)            # backwards by one step
    assert np.ptp(path[:, 1]) < 1e-12 and np.ptp(path[:, 2]) < 1e-12            # along a straight line
    swing_run = next(r for r in runs if swinging[r[0], leg] and len(r) > 400)
    arc = feet[swing_run, leg]
    centre_x = NEUTRAL[leg, 0]
    # (x - xc)^2 / (L/2)^2 + (z - z0)^2 / H^2 = 1: the paper's Figure 4 ellipse
    ellipse = ((arc[:, 0] - centre_x) / (step / 2)) ** 2 + ((arc[:, 2] - NEUTRAL[leg, 2]) / height) ** 2
    assert np.allclose(ellipse, 1.0, atol=0.02)
    assert arc[:, 2].max() == pytest.approx(NEUTRAL[leg, 2] + height, abs=1e-4)


def test_stop_finishes_swings_then_keeps_all_feet_down():
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.03)
    for k in range(1, 1300):
        gait.step(k * DT, DT, Twist(vx=0.1))
    gait.stop()
    for k in range(1300, 3000):
        gait.step(k * DT, DT, Twist())
    assert not gait.state.swinging.any()
    assert np.allclose(gait.state.feet[:, 2], NEUTRAL[:, 2])


def run_gait(gait, seconds, command=Twist(vx=0.1), ground=None):
    """Feet and swing flags per tick; with `ground` (z per leg, body frame) a rigid floor: the feet
    report contact when their target reaches it, and stand on it however far below it their
    targets go."""
    feet, swinging = [], []
    for k in range(1, int(round(seconds / DT)) + 1):
        if ground is None:
            feet.append(gait.step(k * DT, DT, command))
        else:
            feet.append(step_on_floor(gait, k, ground, command)[1])
        swinging.append(gait.state.swinging.copy())
    return np.array(feet), np.array(swinging)


def step_on_floor(gait, k, ground, command=Twist(vx=0.1), silent=NO_LEG):
    """Tick k on a rigid floor (z per leg, body frame): a foot reports contact when its target
    reaches the floor and stands on it however far below it its target goes, but for the legs
    whose sensors are `silent` (a (6,) mask). Returns (the feet where they stand, the gait's targets)."""
    contact = (gait.state.feet[:, 2] <= ground + 1e-9) & ~silent
    measured = gait.state.feet.copy()
    measured[:, 2] = np.maximum(measured[:, 2], ground)
    return measured, gait.step(k * DT, DT, command, contact, measured)


def test_the_swing_command_leads_the_clock_and_stays_on_the_ellipse():
    lead, period, height, speed = 0.033, 1.0, 0.03, 0.1
    gait = GaitGenerator("tripod", NEUTRAL, period, height, lead=lead)
    feet, swinging = run_gait(gait, 3.0, Twist(vx=speed))
    leg, step = 0, speed * 0.5 * period
    swing = np.flatnonzero(swinging[:, leg])
    arc = feet[swing[(swing >= 1000) & (swing < 2000)], leg]       # the swing of the second cycle
    ellipse = ((arc[:, 0] - NEUTRAL[leg, 0]) / (step / 2)) ** 2 + ((arc[:, 2] - NEUTRAL[leg, 2]) / height) ** 2
    assert np.allclose(ellipse, 1.0, atol=0.02)
    # The command is down at the touch-down point `lead` before the scheduled touch-down, and waits.
    down = np.abs(arc[:, 2] - NEUTRAL[leg, 2]) < 1e-12
    assert down[-1] and down.sum() == pytest.approx(lead / DT, abs=2)
    assert np.all(down[np.argmax(down):])
    # It left the ground at once: the first tick is already `lead` into the ellipse.
    assert arc[0, 2] - NEUTRAL[leg, 2] == pytest.approx(height * np.sin(np.pi * (lead + DT) / 0.5), rel=0.05)


def test_a_foot_that_finds_no_ground_reaches_down_a_little_while_the_clock_waits():
    depth = 0.01
    gait = GaitGenerator("wave", NEUTRAL, 1.5, 0.03, TerrainAdaptation.confirmation(0.1, depth), lead=0.02)
    ground = NEUTRAL[:, 2].copy()
    ground[0] -= 0.004                      # the front left foot's ground is 4 mm low
    feet, swinging = run_gait(gait, 3.0, Twist(vx=0.04), ground)
    # Leg 1 swings twice and searches 4 mm at 0.1 m/s each time: the clock waits about 40 ms each.
    assert gait.waited == pytest.approx(0.08, abs=0.01)
    assert feet[:, 0, 2].min() == pytest.approx(ground[0], abs=2e-4)
    # No other leg lifts while it searches: at most one leg is ever in the air (wave).
    assert swinging.sum(axis=1).max() == 1
    # A floor deeper than the search depth: the foot stops at the depth and the walk goes on.
    gait = GaitGenerator("wave", NEUTRAL, 1.5, 0.03, TerrainAdaptation.confirmation(0.1, depth), lead=0.02)
    ground[0] = NEUTRAL[0, 2] - 0.05
    feet, _ = run_gait(gait, 3.0, Twist(vx=0.04), ground)
    assert feet[:, 0, 2].min() == pytest.approx(NEUTRAL[0, 2] - depth, abs=1e-9)
    assert gait.waited == pytest.approx(2 * depth / 0.1, abs=0.01)


def test_touchdown_confirmation_lands_where_the_foot_met_the_ground_then_settles_to_the_stance():
    """A rigid floor 5 mm above the start stance under the front left foot: it lands where it met
    the floor, without a push, then its planted height returns to the start stance's
    (STANCE_SETTLE_TIME): this gait knows no terrain, the stance stays the one it started in."""
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.03, TerrainAdaptation.confirmation(0.1, 0.01), lead=0.02)
    floor = NEUTRAL[:, 2].copy()
    floor[0] += 0.005
    feet, swinging = run_gait(gait, 2.5, Twist(vx=0.1), floor)
    heights, swinging = feet[:, 0, 2], swinging[:, 0]
    landing = np.flatnonzero(np.diff(swinging.astype(int)) == -1)[0] + 1
    assert heights[landing] == pytest.approx(floor[0], abs=2e-4)
    stance = heights[landing:landing + 450] - NEUTRAL[0, 2]
    assert np.all(np.diff(stance) <= 1e-15)                     # settling down, never pushing up
    ticks = int(round(2 * STANCE_SETTLE_TIME / DT))             # first order: e^-2 left after two time constants
    assert stance[ticks] == pytest.approx(0.005 * (1 - DT / STANCE_SETTLE_TIME) ** (ticks + 1), rel=0.05)
    assert abs(stance[-1]) < 1e-6


def test_a_swing_foot_that_meets_a_riser_stops_over_the_ground_and_rises_over_it():
    """Elevator reflex: a step 15 mm high, its riser 5 mm ahead of where the front left foot lifts
    off. Touching the riser on the way up, the foot holds its place over the ground (it does not
    push into the riser) until it is above the step, then goes on along its ellipse and lands on the step."""
    speed, period, top = 0.1, 1.0, 0.015
    adaptation = TerrainAdaptation(search_speed=0.1, search_depth=0.06, touchdown_phase=0.5, plane_time_constant=np.inf)
    gait = GaitGenerator("tripod", NEUTRAL, period, 0.03, adaptation)
    run_gait(gait, 0.5, Twist(vx=speed), NEUTRAL[:, 2])             # to leg 1's lift-off
    riser = gait.state.feet[0, 0] + 0.5 * speed + 0.005             # world x (the body is at 0.5 * speed)
    ground = NEUTRAL[0, 2]
    rows = []
    for k in range(int(0.5 / DT) + 1, int(1.05 / DT) + 1):
        body = k * DT * speed
        feet = gait.state.feet
        # The step is the solid x >= riser, z < top: a foot target inside it stands on its nearer face.
        floor = NEUTRAL[:, 2].copy()
        measured = feet.copy()
        inside_x, inside_z = feet[0, 0] + body - riser, ground + top - feet[0, 2]
        against_riser = 0.0 <= inside_x < inside_z
        if against_riser:
            measured[0, 0] = riser - body
        elif inside_x >= 0.0:
            floor[0] = ground + top
        measured[:, 2] = np.maximum(feet[:, 2], floor)
        contact = feet[:, 2] <= floor + 1e-9
        contact[0] |= against_riser
        gait.step(k * DT, DT, Twist(vx=speed), contact, measured)
        rows.append((body + gait.state.feet[0, 0], gait.state.feet[0, 2] - ground, gait.state.swinging[0]))
    world_x, height, swinging = np.array(rows).T
    climbing = swinging.astype(bool) & (np.cumsum(height >= top) == 0)     # the swing until it clears the step
    assert np.any(world_x[climbing] >= riser - 1e-9)                # it met the riser on the way up
    # ... and never pushed into it, beyond one tick of travel (at most pi / 2 * 5 cm / 500 ticks,
    # 0.16 mm) before each touch is reported.
    assert world_x[climbing].max() - riser < 2e-4
    landing = np.flatnonzero(np.diff(swinging) == -1)[0] + 1
    # On the step (where it touched, then the first tick of settling towards the start stance).
    assert height[landing] == pytest.approx(top * (1 - DT / STANCE_SETTLE_TIME), abs=1e-9)
    ellipse_end = NEUTRAL[0, 0] + 0.25 * speed * period + 1.0 * speed     # world, at t = 1 s
    assert riser + 0.005 < world_x[landing] < ellipse_end           # on the way down to it, over the step


def test_the_walk_plane_is_the_least_squares_plane_of_the_stance_feet():
    """The compiled normal equations and their solve against numpy's least squares; the level
    stance below three feet."""
    rng = np.random.default_rng(0)
    for _ in range(3000):
        feet = NEUTRAL + rng.normal(0.0, 0.02, NEUTRAL.shape)
        stance = rng.random(6) < 0.7
        plane = walk_plane(feet, stance, -0.08)
        if stance.sum() < 3:
            assert plane == (-0.08, 0.0, 0.0)
            continue
        planted = feet[stance]
        design = np.column_stack([np.ones(len(planted)), planted[:, :2]])
        expected, *_ = np.linalg.lstsq(design, planted[:, 2], rcond=None)
        np.testing.assert_allclose(plane, expected, rtol=1e-9, atol=1e-12)


def test_phase_is_the_cycle_fraction_rounded_to_a_billionth():
    gait = GaitGenerator("ripple", NEUTRAL, 1.2, 0.03)
    for t in np.concatenate([np.arange(-2000, 5000) * DT, np.random.default_rng(1).uniform(-5.0, 500.0, 5000)]):
        expected = np.mod(np.round(t / 1.2 - gait.swing_start + gait.duty, 9), 1.0)
        np.testing.assert_allclose(gait.phase(t), expected, rtol=0, atol=1e-12)


STEPPING = TerrainAdaptation(search_speed=0.1, search_depth=0.06, touchdown_phase=0.5, plane_time_constant=np.inf,
                             clearance=0.02, max_swing_height=0.08, edge_margin=0.03, max_step_length=0.08)


def walk_over(gait, seconds, floor_at, speed=0.1, searching=None):
    """Walk `seconds` at `speed` over a rigid floor whose height (body frame) at world x is
    `floor_at(x)` (vectorised), moved with the gait frame's walk-plane following: a foot reports
    contact when its target reaches the floor under it and stands on it. Returns the world x, the
    height and the swing flag of every foot per tick; appends each tick's searching flags to the
    list `searching` if one is given."""
    rows = []
    for k in range(1, int(round(seconds / DT)) + 1):
        body = gait.clock((k - 1) * DT) * speed         # the body stands while the clock waits
        step_on_floor(gait, k, floor_at(gait.state.feet[:, 0] + body) - gait.frame_drop, Twist(vx=speed))
        body = gait.clock(k * DT) * speed
        rows.append((gait.state.feet[:, 0] + body, gait.state.feet[:, 2].copy(), gait.state.swinging.copy()))
        if searching is not None:
            searching.append(gait.state_record[0]["searching"].astype(bool))
    world_x, height, swinging = (np.array(column) for column in zip(*rows))
    return world_x, height, swinging


def landings(swinging, leg):
    return np.flatnonzero(np.diff(swinging[:, leg].astype(int)) == -1) + 1


def test_a_swing_foot_that_finds_a_step_top_on_its_way_down_lands_beyond_where_it_touched():
    """A step 3 cm high whose edge the front left foot passes over at the top of its swing: its
    foot comes down on the step just past the edge (it may be the corner). It does not land there:
    it lands on the step at least edge_margin beyond that first touch."""
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPPING)
    ground, top = NEUTRAL[0, 2], 0.03
    probe = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPPING)
    world_x, height, swinging = walk_over(probe, 1.0, lambda x: np.full_like(x, ground))
    swing = np.flatnonzero(swinging[:, 0])
    descending = swing[(height[swing, 0] - ground < 0.04) & (np.arange(len(swing)) > len(swing) / 2)][0]
    edge = world_x[descending, 0]               # where the foot passes 4 cm above the ground on its way down
    world_x, height, swinging = walk_over(gait, 1.2, lambda x: np.where(x >= edge, ground + top, ground))
    first_touch = np.flatnonzero((world_x[:, 0] >= edge) & (height[:, 0] <= ground + top + 1e-9))[0]
    landing = landings(swinging, 0)[0]
    assert landing > first_touch
    # on the step (where it touched, then the first tick of settling towards the start stance)
    assert height[landing, 0] == pytest.approx(ground + top * (1 - DT / STANCE_SETTLE_TIME), abs=1e-9)
    assert world_x[landing, 0] >= world_x[first_touch, 0] + STEPPING.edge_margin - 1e-6


def test_middle_and_rear_feet_land_on_the_front_feet_footholds_around_an_edge():
    """A step down of 3 cm whose edge lies 5 mm short of where the left middle foot lands on level
    ground (on the edge's corner, with a foot's 1 cm radius). The middle foot lands beyond where
    the left front foot stood instead, away from the edge (by FOOTHOLD_MARGIN, as far as the legs
    reach); the rear foot, whose touch-down lies further from that foothold than the legs reach,
    lands the reach allowance nearer to it; neither lands within 8 mm of the edge."""
    ground, drop, speed = NEUTRAL[0, 2], 0.03, 0.1
    following = dataclasses.replace(STEPPING, plane_time_constant=0.3)
    blind = dataclasses.replace(following, max_swing_height=0.0)
    flat = lambda x: np.full_like(x, ground)
    world_x, _, swinging = walk_over(GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, blind), 6.0, flat)
    middle_flat = world_x[landings(swinging, 1), 1]
    rear_flat = world_x[landings(swinging, 2), 2]
    edge = middle_flat[middle_flat > 0.3][0] - 0.005
    floor_at = lambda x: np.where(x >= edge, ground - drop, ground)
    searching = []
    world_x, height, swinging = walk_over(GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, following), 9.0, floor_at,
                                          searching=searching)
    front_stood = world_x[np.flatnonzero(np.diff(swinging[:, 0].astype(int)) == 1), 0]
    for leg in (1, 2):
        landed = world_x[landings(swinging, leg), leg]
        assert landed.max() > edge + 0.05                   # it walked past the edge
        assert np.abs(landed - edge).min() > 0.008
    middle = world_x[landings(swinging, 1), 1]
    aimed = middle[np.abs(middle - edge) < 0.03]
    assert len(aimed) == 1
    # aimed at the foothold on the lower level, its swing comes down to it: it does not search
    aimed_landing = landings(swinging, 1)[np.abs(middle - edge) < 0.03][0]
    assert aimed[0] > edge
    assert not np.array(searching)[aimed_landing - 300:aimed_landing, 1].any()
    # beyond the front foothold nearest it, on the side away from the edge, by at most the margin
    # (less where the legs reach no further)
    foothold = front_stood[np.argmin(np.abs(front_stood - aimed[0]))]
    beyond = (aimed[0] - foothold) * np.sign(foothold - edge)
    assert 0.005 < beyond <= FOOTHOLD_MARGIN + 1e-9
    # the rear foot's touch-down on level ground nearest the edge, and where it landed instead
    planned = rear_flat[np.argmin(np.abs(rear_flat - edge))]
    foothold = front_stood[front_stood > edge][0]
    reach = 0.5 * (STEPPING.max_step_length - speed * 0.5) + FOOTHOLD_REACH
    assert foothold - planned > reach
    rear = world_x[landings(swinging, 2), 2]
    # it touches the floor LANDING_REACH above its swing's end, a little short of the end's x
    assert np.abs(rear - (planned + reach)).min() < 2e-3


def test_feet_that_lag_their_targets_meet_level_ground_within_their_swings():
    """Feet that follow their targets with a 10 ms lag (the servos) over a level floor: a swing
    ends LANDING_REACH below the ground it expects, so the lagging foot still meets the floor
    before its swing's time is up, and the gait clock never waits for a foot to search."""
    following = dataclasses.replace(STEPPING, plane_time_constant=0.3)
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, following)
    feet = gait.state.feet.copy()
    for k in range(1, 6001):
        feet += (gait.state.feet - feet) * DT / 0.01
        floor = NEUTRAL[0, 2] - gait.frame_drop
        feet[:, 2] = np.maximum(feet[:, 2], floor)
        gait.step(k * DT, DT, Twist(vx=0.1), feet[:, 2] <= floor + 1e-9, feet.copy())
    assert gait.waited == 0.0
    assert gait.clock(6.0) == 6.0


def walk_losing_contact(lost, lost_for, gait_name="tripod"):
    """A walk on a level floor where leg `lost`'s sensor reads no ground for `lost_for` s from
    the tick after it lands past 2 s. Returns when it landed, when another leg next lifted after
    that, and the ticks' times and leg `lost`'s searching flags."""
    following = dataclasses.replace(STEPPING, plane_time_constant=0.3)
    gait = GaitGenerator(gait_name, NEUTRAL, 1.0, 0.05, following)
    floor = NEUTRAL[0, 2] - 0.002       # the floor a little lower than the legs expect it
    lost_leg = np.arange(6) == lost
    landed, lift = np.inf, np.inf
    rows = []
    for k in range(1, 3001):
        t = k * DT
        was_swinging = gait.state.swinging.copy()
        silent = lost_leg if landed < t <= landed + lost_for else NO_LEG
        step_on_floor(gait, k, floor - gait.frame_drop, silent=silent)
        if t > 2.0 and landed == np.inf and was_swinging[lost] and not gait.state.swinging[lost]:
            landed = t
        if landed < t and lift == np.inf and (gait.state.swinging & ~was_swinging & ~lost_leg).any():
            lift = t
        rows.append((t, gait.state_record[0]["searching"][lost] != 0))
    t, searching = (np.array(column) for column in zip(*rows))
    return landed, lift, t, searching


def test_a_foot_that_lost_its_ground_searches_again_before_the_others_lift():
    """A stance foot whose sensor reads no ground for LOST_GROUND_TIME or longer when the other
    tripod is due to lift (it landed on a corner that gave way, or grazed a block's side) reaches
    down for ground again, and the other tripod waits on the ground until it has found it."""
    landed, lift, t, searching = walk_losing_contact(lost=1, lost_for=0.03)
    # the other tripod was due to lift within those 30 ms (as soon as the foot had landed)
    assert landed + 0.03 < 2.6
    searched = t[searching & (t > landed)]
    assert len(searched) > 0 and searched[0] < landed + 0.03
    assert lift > landed + 0.03
    assert lift > searched[-1]


def test_a_foot_whose_sensor_chatters_holds_the_lift_without_searching():
    """A landed foot's sensor that reads no ground for less than LOST_GROUND_TIME (a landing on
    rigid ground chatters): the other tripod waits until it reads ground again, and the foot
    does not search."""
    landed, lift, t, searching = walk_losing_contact(lost=1, lost_for=0.015)
    # the other tripod was due to lift 11 ms after the landing, within those 15 ms
    assert lift > landed + 0.015
    assert lift < landed + 0.02
    assert not searching[t > landed].any()


@pytest.mark.parametrize("gait_name", ["ripple", "wave"])
def test_with_four_feet_down_or_more_a_foot_without_ground_holds_no_lift(gait_name):
    """Ripple and wave leave four or five feet down: a foot whose sensor reads no ground for
    0.2 s (more than the time between two lifts) neither searches again nor holds the next lift
    (on rigid ground their lightly loaded feet read no ground for long stretches)."""
    _, lift, _, _ = walk_losing_contact(lost=1, lost_for=0.0, gait_name=gait_name)
    landed, lift_losing, t, searching = walk_losing_contact(lost=1, lost_for=0.2, gait_name=gait_name)
    assert landed + 0.2 > lift_losing
    assert lift_losing == lift
    assert not searching[t > landed].any()


def test_only_gaits_that_leave_three_feet_down_or_fewer_stand_on_three_feet():
    assert [GAITS.resolve(name).fewest_feet_down for name in ("tripod", "ripple", "wave", "stand")] == [3, 4, 5, 6]
    assert GaitPattern(0.5, (0.0,) * 6).fewest_feet_down == 0
    for name, on_three in (("tripod", 1), ("ripple", 0), ("wave", 0)):
        assert GaitGenerator(name, NEUTRAL, 1.0, 0.05, STEPPING).parameters["on_three_feet"][0] == on_three


def test_a_foot_at_the_bottom_of_its_search_does_not_hold_the_walk():
    """A foot whose ground lies deeper than its search reaches lands at the search's bottom, in
    the air; it has nothing left to search, so the other legs lift on schedule after it."""
    shallow = dataclasses.replace(STEPPING, plane_time_constant=0.3, search_depth=0.01)
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, shallow)
    floor = NEUTRAL[:, 2].copy()
    floor[1] -= 0.2                         # the left middle foot's ground is out of its reach
    for k in range(1, 4001):
        step_on_floor(gait, k, floor - gait.frame_drop)
    # it searched 1 cm at 0.1 m/s in each of its four swings, the clock waiting 0.1 s each time
    assert gait.waited == pytest.approx(0.4, abs=0.05)


def test_the_ground_slope_is_read_from_the_front_footholds_only_where_they_lie_on_a_line():
    footholds = np.full((2, FOOTHOLDS, 3), np.nan)
    x = np.array([-0.3, -0.2, -0.1, 0.0, 0.1, 0.2])
    for side, (y, offset) in enumerate(((0.16, -0.09), (-0.16, -0.07))):     # the sides at other heights
        footholds[side] = np.column_stack([x, np.full(6, y), offset + np.tan(np.radians(20.0)) * x])
    count = np.array([FOOTHOLDS, FOOTHOLDS])
    assert footholds_slope(footholds, count) == pytest.approx(np.tan(np.radians(20.0)), rel=1e-12)
    assert footholds_slope(footholds, np.array([3, FOOTHOLDS])) == 0.0          # too few yet
    footholds[0, -1, 2] += 0.03                                                # a 3 cm step among them
    assert footholds_slope(footholds, count) == 0.0


@pytest.mark.parametrize("ground, aims", [("ramp", False), ("step", True)])
def test_rear_feet_aim_at_front_footholds_around_an_edge_but_not_on_an_even_ramp(ground, aims):
    """The left rear foot lifts with its planned touch-down between two footholds 3 cm apart
    that differ by 1.1 cm in height: on an even 20 deg ramp (the slope of the front footholds
    explains the rise) it keeps its touch-down, which the uphill shift moves; with a 3 cm step
    between them (the same heights elsewhere level) it aims at the nearer foothold."""
    from testbed.control.gait import _choose_footholds, _touchdown
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, dataclasses.replace(STEPPING, slope_shift=0.08))
    s, speed, rear = gait.state_record[0], 0.1, 2
    twist = (speed, 0.0, 0.0)
    planned = _touchdown(gait.parameters, twist)[rear, 0]
    x = planned + speed * 0.5 + np.array([-0.075, -0.045, -0.015, 0.015, 0.045, 0.075])   # oldest first
    z = np.tan(np.radians(20.0)) * x if ground == "ramp" else np.where(x > planned + speed * 0.5, 0.03, 0.0)
    for side, y in enumerate((0.16, -0.16)):
        s["footholds"][side] = np.column_stack([x, np.full(FOOTHOLDS, y), z - 0.09])
        s["stood"][side, :FOOTHOLDS] = s["footholds"][side]
    s["foothold_count"][:] = s["stood_count"][:] = FOOTHOLDS
    lifting = np.zeros(6, dtype=bool)
    lifting[rear] = True
    _choose_footholds(gait.parameters, s, lifting, twist, footholds_slope(s["footholds"], s["foothold_count"]))
    assert (s["aim"][rear] in (2, 3)) if aims else (s["aim"][rear] == -1)


def test_a_swing_foot_short_of_the_riser_it_met_holds_its_place_until_it_is_up_and_the_edge_rises_with_it():
    """Foot 0 met a riser at x = 0.20 m (gait frame), 3 cm above its lift-off, on its way down.
    While the foot itself is lower than the edge plus the clearance by more than RISER_HEIGHT, its
    target rises there but stays short of the riser (it does not push into the face); once the
    foot is up, the target goes on. A later touch short of the riser, higher than the edge,
    raises the edge."""
    from testbed.control.gait import RISER_HEIGHT, _keep_over_edges, _short_of_edges
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPPING)
    parameters, record = gait.parameters, gait.state_record
    s = record[0]
    ground = NEUTRAL[0, 2]
    s["liftoff"][0] = (0.15, NEUTRAL[0, 1], ground)
    s["edge"][0] = (0.20, ground + 0.03)
    in_swing = np.array([True, False, False, False, False, False])
    top = ground + 0.03 + STEPPING.clearance
    measured = gait.state.feet.copy()
    for foot_z, held in ((ground + 0.03, True), (top - RISER_HEIGHT + 1e-4, False)):
        s["feet"][0] = (0.215, NEUTRAL[0, 1], ground + 0.01)       # the ellipse's target, inside the step
        measured[0] = (0.20, NEUTRAL[0, 1], foot_z)
        _keep_over_edges(parameters, s, in_swing, measured)
        assert s["feet"][0, 2] == pytest.approx(top)
        assert s["feet"][0, 0] == pytest.approx(0.20 if held else 0.215)
    touched = in_swing.copy()
    stance = ~in_swing
    measured[0] = (0.20, NEUTRAL[0, 1], ground + 0.04)
    short = _short_of_edges(parameters, s, touched, measured, stance)
    assert short[0] and s["edge"][0, 1] == pytest.approx(ground + 0.04) and s["edge"][0, 0] == pytest.approx(0.20)
    measured[0] = (0.20, NEUTRAL[0, 1], ground + 0.035)               # lower: the edge stays
    _short_of_edges(parameters, s, touched, measured, stance)
    assert s["edge"][0, 1] == pytest.approx(ground + 0.04)


def test_a_follower_aimed_down_a_step_does_not_land_on_the_upper_treads_corner():
    """The left rear foot lifted on the upper level and aims at a foothold 4.2 cm lower, beyond a
    step down. A touch on its way down at about its lift-off height, short of that foothold, is
    the upper tread's corner: an edge, where it does not land (without the aim it would); a
    touch at the foothold's height lands, and so does one at the lift-off height beyond the
    foothold (ground as rough blocks place it: the foothold's recorded height is off)."""
    from testbed.control.gait import _short_of_edges
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.05, STEPPING)
    parameters, s = gait.parameters, gait.state_record[0]
    rear, ground = 2, NEUTRAL[2, 2]
    s["liftoff"][rear] = (-0.20, NEUTRAL[rear, 1], ground)
    s["stood"][0, 0] = (-0.05, NEUTRAL[rear, 1], ground - 0.042)
    s["stood_count"][0] = 1
    touched = np.zeros(6, dtype=bool)
    touched[rear] = True
    measured = gait.state.feet.copy()
    measured[rear] = (-0.08, NEUTRAL[rear, 1], ground - 0.002)
    assert not _short_of_edges(parameters, s, touched, measured, ~touched)[rear]       # no aim: it lands
    s["aim"][rear] = 0
    assert _short_of_edges(parameters, s, touched, measured, ~touched)[rear]
    assert tuple(s["edge"][rear]) == pytest.approx((-0.08, ground - 0.002))
    s["edge"][rear] = np.nan
    measured[rear] = (-0.06, NEUTRAL[rear, 1], ground - 0.041)
    assert not _short_of_edges(parameters, s, touched, measured, ~touched)[rear]
    measured[rear] = (-0.045, NEUTRAL[rear, 1], ground - 0.002)
    assert not _short_of_edges(parameters, s, touched, measured, ~touched)[rear]


LOADING = TerrainAdaptation(search_speed=0.1, search_depth=0.06, touchdown_phase=0.5, plane_time_constant=0.3,
                            load_time=0.06)


def test_the_lifts_do_not_wait_for_the_load_time_on_even_ground():
    """On even ground no landing is off the plane of the feet that stood before it: the lifts do
    not wait (the next test: they do after one that is)."""
    waits = {}
    for name, period, speed, ground in (("tripod", 1.0, 0.1, NEUTRAL[:, 2]), ("ripple", 1.2, 0.06, NEUTRAL[:, 2])):
        for adaptation in (LOADING, dataclasses.replace(LOADING, load_time=0.0)):
            gait = GaitGenerator(name, NEUTRAL, period, 0.03, adaptation)
            run_gait(gait, 3.0, Twist(vx=speed), ground)
            waits[name, ground[0], adaptation.load_time] = gait.waited
    assert waits["tripod", NEUTRAL[0, 2], 0.06] == waits["tripod", NEUTRAL[0, 2], 0.0]
    assert waits["ripple", NEUTRAL[0, 2], 0.06] == waits["ripple", NEUTRAL[0, 2], 0.0]


def test_a_foot_that_slides_off_as_it_takes_weight_searches_again_before_any_leg_lifts():
    """The front left foot lands on a block's corner (2 cm up) and slides off it 20 ms later, 3 cm down:
    its contact is lost within the load time, so it reaches down again for the ground below while
    the other tripod stands, and that one lifts only once the foot has held its new ground for
    the load time."""
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.03, LOADING)
    ground = NEUTRAL[:, 2].copy()
    ground[0] += 0.02
    landed = slid = None
    heights, swinging = [], []
    for k in range(1, 2800):
        was_swinging = gait.state.swinging[0]
        step_on_floor(gait, k, ground)
        if landed is None and k * DT > 1.2 and was_swinging and not gait.state.swinging[0]:
            landed = k
        if landed is not None and slid is None and k == landed + 20:
            ground[0] -= 0.03                   # off the corner
            slid = k
        heights.append(gait.state.feet[0, 2])
        swinging.append(gait.state.swinging.copy())
    heights, swinging = np.array(heights), np.array(swinging)
    landed, slid = landed - 1, slid - 1                         # rows of the lists
    assert swinging[slid + 1, 0]                                    # back in the air
    relanded = slid + 1 + np.argmax(~swinging[slid + 1:, 0])
    assert heights[relanded] == pytest.approx(ground[0], abs=2e-4)  # down on the ground below
    others = swinging[:, [1, 3, 5]].any(axis=1)                 # the tripod it relieves
    assert not others[landed:relanded].any()
    first_lift = relanded + np.argmax(others[relanded:])
    assert others[first_lift] and (first_lift - relanded) * DT >= 0.06 - 1.5 * DT


def test_a_foot_landed_on_uneven_ground_is_pressed_into_it_over_its_load_time_and_rises_back():
    """The front left foot lands on a block 2 cm up: over the load time its target goes
    `load_preload` below where it touched (it takes weight while the other tripod stands), then
    rises back as fast once it holds; the other tripod lifts only after the load time."""
    adaptation = dataclasses.replace(LOADING, load_preload=0.003)
    gait = GaitGenerator("tripod", NEUTRAL, 1.0, 0.03, adaptation)
    ground = NEUTRAL[:, 2].copy()
    ground[0] += 0.02
    pressed, landed, relieved_lift = [], None, None
    for k in range(1, 1400):
        was_swinging = gait.state.swinging[0]
        measured, _ = step_on_floor(gait, k, ground)
        if landed is None and k * DT > 0.6 and was_swinging and not gait.state.swinging[0]:
            landed, touched = k, measured[0, 2] - gait.frame_drop
        if landed is not None:
            # below the touch, in the frame that does not follow the walk plane
            pressed.append(touched - (gait.state.feet[0, 2] + gait.frame_drop))
            if relieved_lift is None and gait.state.swinging[[1, 3, 5]].any():
                relieved_lift = k
    pressed = np.array(pressed)
    load_ticks = int(round(adaptation.load_time / DT))
    assert pressed.max() == pytest.approx(0.003, abs=5e-5)          # +- a tick of the walk plane's following
    assert np.argmax(pressed) == pytest.approx(load_ticks, abs=1)
    assert np.all(np.diff(pressed[:load_ticks]) > 0)                 # down steadily
    assert np.abs(pressed[2 * load_ticks + 2:]).max() < 5e-5       # back up, until it lifts
    assert (relieved_lift - landed) * DT >= adaptation.load_time - 1.5 * DT
