"""Static stability: the support polygon of the stance feet and the centre of mass's margin.

Both run once per physics step on at most six points. scipy's ConvexHull (Qhull) gives the same
hull but costs about 70 us a call, and the same algorithms in Python about 30 us: they are
compiled with numba (about 1 us each).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.world.terrain import candidates_by_rule, closest_distance


def support_polygon(points_xy: np.ndarray) -> np.ndarray:
    """(K, 2) counter-clockwise convex hull of the contact points (fewer than 3: the points,
    sorted; collinear points: the two extremes). Andrew's monotone chain."""
    return _monotone_chain(np.ascontiguousarray(points_xy, dtype=float).reshape(-1, 2))


def stability_margin(polygon: np.ndarray, com_xy: np.ndarray) -> float:
    """Distance from the centre of mass's ground projection to the nearest polygon edge, m:
    positive inside, negative outside (and for fewer than three feet, minus the distance to the
    segment or point they form; -inf with no foot down)."""
    return _margin(np.ascontiguousarray(polygon, dtype=float).reshape(-1, 2), float(com_xy[0]), float(com_xy[1]))


@njit(cache=True)
def stance_support(last_touch: np.ndarray, contact: np.ndarray, swinging: np.ndarray, t: float, feet: np.ndarray,
                   com: np.ndarray, debounce: float, resting: np.ndarray) -> tuple[np.ndarray, float, int]:
    """The support polygon of the feet touching the ground now or within `debounce` s, or
    `resting` (6,) bool on it, and the centre of mass's margin in it, in one compiled call:
    `last_touch` (6,) holds each foot's latest touch time and is updated in place from `contact`
    (6,) bool at time t; `feet` (6, 3); `com` is read at [0] and [1]. Third, the stance feet (not
    `swinging`) that neither touch the ground nor touched it within `debounce`, as bits (leg i:
    1 << i): the feet whose `resting` the caller may want to know (all False in a first call)
    before asking again."""
    supporting = np.empty(len(feet), np.bool_)
    late = 0
    for leg in range(len(feet)):
        if contact[leg]:
            last_touch[leg] = t
        recent = t - last_touch[leg] <= debounce
        if not (swinging[leg] or recent):
            late |= 1 << leg
        supporting[leg] = resting[leg] or recent
    polygon = _monotone_chain(np.ascontiguousarray(feet[supporting, :2]))
    return polygon, _margin(polygon, com[0], com[1]), late


@njit(cache=True)
def stance_support_on_terrain(last_touch, contact, swinging, t, feet, com, debounce, radius, tolerance, box_centers,
                              box_halves, box_rotations, rule, rule_data):
    """The support polygon and the margin of `stance_support` in one compiled call with the terrain's
    answer for the late stance feet: a late foot rests on the ground if its sphere (`radius`) is
    within `tolerance` of the terrain (Terrain.closest, its candidate boxes by the terrain's
    `rule`, Terrain.candidate_rule), and the support is asked again with the resting feet."""
    resting = np.zeros(len(feet), np.bool_)
    polygon, margin, late = stance_support(last_touch, contact, swinging, t, feet, com, debounce, resting)
    if late == 0:
        return polygon, margin
    candidates = candidates_by_rule(feet, rule, rule_data)
    for leg in range(len(feet)):
        if (late >> leg) & 1:
            distance = closest_distance(feet[leg], box_centers, box_halves, box_rotations, candidates[leg])
            resting[leg] = distance - radius <= tolerance
    polygon, margin, _ = stance_support(last_touch, contact, swinging, t, feet, com, debounce, resting)
    return polygon, margin


@njit(cache=True)
def _monotone_chain(points):
    n = len(points)
    order = np.arange(n)
    for i in range(1, n):           # insertion sort by (x, y): at most six points
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
    n = len(polygon)
    if n == 0:
        return -np.inf
    if n < 3:
        return -_distance_to_segment(x, y, polygon[0], polygon[n - 1])
    # Left-hand normal distance: positive inside a counter-clockwise polygon.
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
