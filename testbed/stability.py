"""Static stability: the support polygon of the stance feet and the centre of mass's margin."""

from __future__ import annotations

import numpy as np


def support_polygon(points_xy: np.ndarray) -> np.ndarray:
    """(K, 2) counter-clockwise convex hull of the contact points (fewer than 3: the points;
    collinear points: the two extremes).

    Andrew's monotone chain on at most six points: scipy's ConvexHull (Qhull) gives the same hull
    but costs about 70 us a call, 7 % of a 1 kHz tick, against about 10 us here."""
    points = sorted(map(tuple, np.asarray(points_xy, dtype=float)))
    if len(points) < 3:
        return np.array(points).reshape(-1, 2)

    def half(sequence):
        chain: list[tuple[float, float]] = []
        for p in sequence:
            while len(chain) >= 2 and _turn(chain[-2], chain[-1], p) <= 0:
                chain.pop()
            chain.append(p)
        return chain[:-1]

    hull = half(points) + half(reversed(points))
    return np.array(hull).reshape(-1, 2)


def _turn(o, a, b) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def stability_margin(polygon: np.ndarray, com_xy: np.ndarray) -> float:
    """Distance from the centre of mass's ground projection to the nearest polygon edge, m:
    positive inside, negative outside (and for fewer than three feet, minus the distance to the
    segment or point they form; -inf with no foot down)."""
    if len(polygon) == 0:
        return -np.inf
    if len(polygon) < 3:
        return -_distance_to_segment(com_xy, polygon[0], polygon[-1])
    start, end = polygon, np.roll(polygon, -1, axis=0)
    edge = end - start
    length = np.linalg.norm(edge, axis=1)
    # Left-hand normal distance: positive inside a counter-clockwise polygon.
    signed = (edge[:, 0] * (com_xy[1] - start[:, 1]) - edge[:, 1] * (com_xy[0] - start[:, 0])) / length
    if np.all(signed >= 0):
        return float(signed.min())
    return -min(_distance_to_segment(com_xy, a, b) for a, b in zip(start, end))


def _distance_to_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    denominator = float(ab @ ab)
    fraction = 0.0 if denominator == 0 else float(np.clip((point - a) @ ab / denominator, 0.0, 1.0))
    return float(np.linalg.norm(point - (a + fraction * ab)))
