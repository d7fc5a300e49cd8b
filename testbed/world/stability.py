"""Static stability: the support polygon of the stance feet and the centre of mass's margin.

`support_polygon` and `stability_margin` state the laws in Python and numpy. Both run once per
physics step on at most six points, where a Python call costs more than the whole hull: the run
loop asks the compiled `stance_support` / `stance_support_on_terrain`, whose kernels
(`_monotone_chain`, `_margin`) are the same algorithms beside them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.world.records import one_record, raw, the_record
from testbed.world.terrain import BOX, CANDIDATE_RULE, candidates_by_rule, closest_distance

LEGS = 6
CONTACT_DEBOUNCE = 0.005  # s: a foot that touched the ground this recently still supports
GROUND_TOLERANCE = 0.001  # m: a stance foot this close to the ground still supports
# The support tracker's settings and its memory: `debounce` s a touch keeps counting, `foot_radius`
# m, `ground_tolerance` m a stance foot may float above the ground and still support, `last_touch`
# each foot's latest touch time (s, updated in place).
SUPPORT = np.dtype([("debounce", np.float64), ("foot_radius", np.float64), ("ground_tolerance", np.float64),
                    ("last_touch", np.float64, (LEGS,))])


def support_record(debounce: float, foot_radius: float, ground_tolerance: float) -> np.ndarray:
    """The bytes of a SUPPORT record with no touch yet (last_touch = -inf), as the kernels take it;
    `support_view` gives its fields."""
    return raw(one_record(SUPPORT, debounce=debounce, foot_radius=foot_radius, ground_tolerance=ground_tolerance,
                          last_touch=-np.inf))


def support_view(support_raw: np.ndarray) -> np.void:
    """The SUPPORT record of `support_record`'s bytes (a view)."""
    return support_raw.view(SUPPORT)[0]


# ---------------------------------------------------------------- the laws
def support_polygon(points_xy: np.ndarray) -> np.ndarray:
    """(K, 2) counter-clockwise convex hull of the contact points (fewer than 3: the points,
    sorted; collinear points: the two extremes). Andrew's monotone chain."""
    points = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    order = sorted(range(len(points)), key=lambda i: (points[i, 0], points[i, 1]))
    if len(order) < 3:
        return points[order]

    def half_hull(indices: list[int]) -> list[int]:
        chain: list[int] = []
        for i in indices:
            while len(chain) >= 2 and _cross(points[chain[-2]], points[chain[-1]], points[i]) <= 0:
                chain.pop()
            chain.append(i)
        return chain[:-1]             # each half's last point starts the other half

    return points[half_hull(order) + half_hull(order[::-1])]


def stability_margin(polygon: np.ndarray, com_xy: np.ndarray) -> float:
    """Distance from the centre of mass's ground projection to the nearest polygon edge, m:
    positive inside, negative outside (and for fewer than three feet, minus the distance to the
    segment or point they form; -inf with no foot down)."""
    polygon = np.asarray(polygon, dtype=float).reshape(-1, 2)
    com = np.asarray(com_xy, dtype=float)[:2]
    if len(polygon) == 0:
        return -math.inf
    if len(polygon) < 3:
        return -_distance_to_segments(com, polygon[:1], polygon[-1:])[0]
    starts, ends = polygon, np.roll(polygon, -1, axis=0)
    edges = ends - starts
    # Left-hand normal distance: positive inside a counter-clockwise polygon.
    signed = (edges[:, 0] * (com[1] - starts[:, 1]) - edges[:, 1] * (com[0] - starts[:, 0])) / np.sqrt(
        edges[:, 0] ** 2 + edges[:, 1] ** 2)
    inside = float(signed.min())
    return inside if inside >= 0.0 else -float(_distance_to_segments(com, starts, ends).min())


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """z of (a - o) x (b - o): positive for a left turn."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _distance_to_segments(point: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    along = ends - starts
    length_sq = np.sum(along * along, axis=1)
    fraction = np.clip(np.sum((point - starts) * along, axis=1) / np.where(length_sq == 0.0, 1.0, length_sq), 0.0, 1.0)
    fraction = np.where(length_sq == 0.0, 0.0, fraction)
    return np.sqrt(np.sum((point - (starts + fraction[:, None] * along)) ** 2, axis=1))


def feet_on_ground(terrain, feet: np.ndarray, foot_radius: float) -> np.ndarray:
    """Whether each foot's sphere (centres (..., 3)) lies within GROUND_TOLERANCE of the terrain
    (a `Terrain`): the feet that rest on the ground whatever a contact model's flags say.
    `resting_feet` is the same rule per step, compiled."""
    distance, _ = terrain.closest(feet.reshape(-1, 3))
    return (distance - foot_radius <= GROUND_TOLERANCE).reshape(feet.shape[:-1])


# ---------------------------------------------------------------- per step, compiled
@njit(cache=True)
def stance_support(support_raw, t, contact, swinging, feet, com, resting):
    """The support polygon of the feet touching the ground now or within the SUPPORT record's
    debounce, or `resting` (6,) bool on it, and the centre of mass's margin in it, in one compiled
    call. The record (`support_raw`, its bytes: `support_record`) holds each foot's latest touch time,
    updated in place from `contact` (6,) bool at time t; `feet` (6, 3); `com` (3,), of which x and y count.
    Third, the stance feet (not `swinging`) that neither touch the ground nor touched it within the
    debounce, as bits (leg i: 1 << i): the feet whose `resting` the caller may want to know (all
    False in a first call) before asking again."""
    record = the_record(support_raw.view(SUPPORT))
    last_touch = record.last_touch
    supporting = np.empty(len(feet), np.bool_)
    late = 0
    for leg in range(len(feet)):
        if contact[leg]:
            last_touch[leg] = t
        recent = t - last_touch[leg] <= record.debounce
        if not (swinging[leg] or recent):
            late |= 1 << leg
        supporting[leg] = resting[leg] or recent
    polygon = _monotone_chain(np.ascontiguousarray(feet[supporting, :2]))
    return polygon, _margin(polygon, com[0], com[1]), late


@njit(cache=True)
def stance_support_on_terrain(support_raw, t, contact, swinging, feet, com, boxes_raw, rule_raw):
    """The support polygon and the margin of `stance_support` in one compiled call with the terrain's
    answer for the late stance feet: a late foot rests on the ground if its sphere (the SUPPORT
    record's foot_radius) is within the record's ground_tolerance of the terrain (its BOX records,
    the candidates by its CANDIDATE_RULE; both as bytes), and the support is asked again with the
    resting feet."""
    resting = np.zeros(len(feet), np.bool_)
    polygon, margin, late = stance_support(support_raw, t, contact, swinging, feet, com, resting)
    if late == 0:
        return polygon, margin
    resting = resting_feet(support_raw, feet, late, boxes_raw, candidates_by_rule(feet, rule_raw.view(CANDIDATE_RULE)))
    polygon, margin, _ = stance_support(support_raw, t, contact, swinging, feet, com, resting)
    return polygon, margin


@njit(cache=True)
def resting_feet(support_raw, feet, late, boxes_raw, candidates):
    """(6,) bool: the feet among `late` (bits, leg i: 1 << i) whose sphere (the SUPPORT record's
    foot_radius) lies within the record's ground_tolerance of the terrain's BOX records (bytes),
    each foot among its row of `candidates`."""
    record, boxes = the_record(support_raw.view(SUPPORT)), boxes_raw.view(BOX)
    resting = np.zeros(len(feet), np.bool_)
    for leg in range(len(feet)):
        if (late >> leg) & 1:
            distance = closest_distance(feet[leg], boxes, candidates[leg])
            resting[leg] = distance - record.foot_radius <= record.ground_tolerance
    return resting


@njit(cache=True)
def _monotone_chain(points):
    """support_polygon, compiled."""
    n = len(points)
    order = np.arange(n)
    for i in range(1, n):           # insertion sort by (x, y), stable: at most six points
        j = i
        while j > 0 and _before(points[order[j]], points[order[j - 1]]):
            order[j], order[j - 1] = order[j - 1], order[j]
            j -= 1
    if n < 3:
        return points[order].copy()
    hull = np.empty(2 * n, np.int64)
    size = 0
    for sweep in range(2):          # lower hull left to right, upper hull right to left
        start = size
        for step in range(n):
            p = order[step] if sweep == 0 else order[n - 1 - step]
            while size - start >= 2 and _turn(points[hull[size - 2]], points[hull[size - 1]], points[p]) <= 0:
                size -= 1
            hull[size] = p
            size += 1
        size -= 1                   # each half's last point starts the other half
    return points[hull[:size]].copy()


@njit(cache=True)
def _before(a, b) -> bool:
    return a[0] < b[0] or (a[0] == b[0] and a[1] < b[1])


@njit(cache=True)
def _turn(o, a, b) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


@njit(cache=True)
def _margin(polygon, x, y) -> float:
    """stability_margin, compiled."""
    n = len(polygon)
    if n == 0:
        return -np.inf
    if n < 3:
        return -_distance_to_segment(x, y, polygon[0], polygon[n - 1])
    inside, outside = np.inf, np.inf
    for i in range(n):
        a, b = polygon[i], polygon[(i + 1) % n]
        ex, ey = b[0] - a[0], b[1] - a[1]
        signed = (ex * (y - a[1]) - ey * (x - a[0])) / math.sqrt(ex * ex + ey * ey)
        inside = min(inside, signed)
        outside = min(outside, _distance_to_segment(x, y, a, b))
    return inside if inside >= 0.0 else -outside


@njit(cache=True)
def _distance_to_segment(x, y, a, b) -> float:
    abx, aby = b[0] - a[0], b[1] - a[1]
    denominator = abx * abx + aby * aby
    fraction = 0.0 if denominator == 0.0 else min(max(((x - a[0]) * abx + (y - a[1]) * aby) / denominator, 0.0), 1.0)
    dx, dy = x - (a[0] + fraction * abx), y - (a[1] + fraction * aby)
    return math.sqrt(dx * dx + dy * dy)
