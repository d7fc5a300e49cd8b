"""The geometry every terrain is made of: boxes, the signed distance of points to them, spheres
indenting them, and the rules that name the boxes near a point.

The compliant contact uses the signed distance from points to the union of boxes with the surface
normal there, so a foot meeting the riser of a step is pushed back by the riser rather than lifted
vertically onto the top.

The distance laws are written once in numpy (`distances_to_boxes`, `sphere_contacts`); compiled
kernels beside them (`box_distance`, `sphere_contact_arrays`, `closest_distance`) serve the
per-step contact and support checks, which ask six points against a few boxes every physics step.
Kernels take the boxes as a structured array of `BOX` records and a terrain's candidate boxes as a
one-element `CANDIDATE_RULE` array: fields by name, never by position. A candidate index of
NO_BOX (-1) pads a row of candidates that holds fewer boxes than its neighbours: it names no box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from testbed.world.records import one_record, the_record

BASE_DEPTH = 0.1   # m, thickness of ground below its lowest top surface
MAX_BLOCKS = 20000      # boxes DART and the recorder can take
NO_BOX = -1        # a candidate index naming no box

BOX = np.dtype([("center", np.float64, (3,)), ("half_extents", np.float64, (3,)), ("rotation", np.float64, (3, 3))])

# How compiled code finds Terrain.candidates (`candidates_by_rule`): every one of `boxes` boxes, or
# the blocks around each point on a grid of blocks (x0, y0, cell, nx, ny: GridTerrain).
EVERY_BOX, BLOCKS_AROUND = 0, 1
CANDIDATE_RULE = np.dtype([("kind", np.int64), ("boxes", np.int64), ("x0", np.float64), ("y0", np.float64),
                           ("cell", np.float64), ("nx", np.int64), ("ny", np.int64)])


def candidate_rule(kind: int, *, boxes: int = 0, x0: float = 0.0, y0: float = 0.0, cell: float = 1.0, nx: int = 1,
                   ny: int = 1) -> np.ndarray:
    """A one-element CANDIDATE_RULE array (the form compiled code takes it in)."""
    return one_record(CANDIDATE_RULE, kind=kind, boxes=boxes, x0=x0, y0=y0, cell=cell, nx=nx, ny=ny)


@dataclass(frozen=True)
class Boxes:
    """N oriented boxes: centres (N, 3), half extents (N, 3), rotations world_from_box (N, 3, 3)."""
    centers: np.ndarray
    half_extents: np.ndarray
    rotations: np.ndarray

    def __len__(self) -> int:
        return len(self.centers)

    @cached_property
    def records(self) -> np.ndarray:
        """The boxes as an (N,) structured array of BOX records, the form kernels take them in."""
        records = np.zeros(len(self), BOX)
        records["center"], records["half_extents"] = self.centers, self.half_extents
        records["rotation"] = self.rotations
        return records


def axis_aligned_boxes(x0: float, x1: float, y0: float, y1: float, tops: np.ndarray, bottom: float) -> Boxes:
    """Boxes spanning [x0, x1] x [y0, y1] arrays with the given top heights and a common bottom."""
    x0, x1, y0, y1, tops = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x0, x1, y0, y1, tops))
    centers = np.column_stack([(x0 + x1) / 2, (y0 + y1) / 2, (tops + bottom) / 2])
    half = np.column_stack([(x1 - x0) / 2, (y1 - y0) / 2, (tops - bottom) / 2])
    return Boxes(centers, half, np.broadcast_to(np.eye(3), (len(centers), 3, 3)).copy())


_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)


def box_footprints(boxes: Boxes) -> np.ndarray:
    """(N, 4) x_min, x_max, y_min, y_max of each box seen from above."""
    corners = boxes.centers[:, None, :] + np.einsum("nij,nkj->nki", boxes.rotations,
                                                    _CORNER_SIGNS[None, :, :] * boxes.half_extents[:, None, :])
    low, high = corners[..., :2].min(axis=1), corners[..., :2].max(axis=1)
    return np.column_stack([low[:, 0], high[:, 0], low[:, 1], high[:, 1]])


# ---------------------------------------------------------------- the distance to a box
def distances_to_boxes(points: np.ndarray, boxes: Boxes, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (N, K) from each point to each of its candidate boxes (N, K indices) and the
    outward unit normal (N, K, 3) of that box's nearest surface. Negative distance means inside.
    Outside a box: the distance from its nearest point, the normal along it. Inside: the face
    nearest the point (the first of equally near ones). NO_BOX: infinite distance, zero normal."""
    points, candidates = np.asarray(points, dtype=float), np.asarray(candidates)
    missing = candidates == NO_BOX
    if missing.any():
        distance, normal = distances_to_boxes(points, boxes, np.where(missing, 0, candidates))
        return np.where(missing, np.inf, distance), np.where(missing[..., None], 0.0, normal)
    rotation = boxes.rotations[candidates]                                      # (N, K, 3, 3)
    local = np.einsum("nkji,nkj->nki", rotation, points[:, None, :] - boxes.centers[candidates])
    excess = np.abs(local) - boxes.half_extents[candidates]
    outside = np.sqrt(np.sum(np.maximum(excess, 0.0) ** 2, axis=-1))
    face = np.argmax(excess, axis=-1)[..., None]
    face_excess = np.take_along_axis(excess, face, -1)[..., 0]
    towards_face = np.where(np.take_along_axis(local, face, -1) >= 0.0, 1.0, -1.0)
    on_face = (np.arange(3) == face) * towards_face
    off_box = np.maximum(excess, 0.0) * np.sign(local) / np.maximum(outside, 1e-12)[..., None]
    local_normal = np.where((outside > 1e-12)[..., None], off_box, on_face)
    normal = np.einsum("nkij,nkj->nki", rotation, local_normal)
    return outside + np.minimum(face_excess, 0.0), normal


@njit(cache=True)
def box_distance(point, box, normal) -> float:
    """distances_to_boxes for one point and one BOX record, compiled; writes the normal into `normal`."""
    dx, dy, dz = point[0] - box.center[0], point[1] - box.center[1], point[2] - box.center[2]
    rotation, half = box.rotation, box.half_extents
    local = (rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz,
             rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz,
             rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz)
    excess = (abs(local[0]) - half[0], abs(local[1]) - half[1], abs(local[2]) - half[2])
    outside_sq, face = 0.0, 0
    for i in range(3):
        if excess[i] > 0.0:
            outside_sq += excess[i] * excess[i]
        if excess[i] > excess[face]:
            face = i
    outside_norm = math.sqrt(outside_sq)
    if outside_norm > 1e-12:
        n0 = max(excess[0], 0.0) * np.sign(local[0]) / outside_norm
        n1 = max(excess[1], 0.0) * np.sign(local[1]) / outside_norm
        n2 = max(excess[2], 0.0) * np.sign(local[2]) / outside_norm
    else:
        side = 1.0 if local[face] >= 0.0 else -1.0
        n0, n1, n2 = (side if face == 0 else 0.0), (side if face == 1 else 0.0), (side if face == 2 else 0.0)
    for i in range(3):
        normal[i] = rotation[i, 0] * n0 + rotation[i, 1] * n1 + rotation[i, 2] * n2
    return outside_norm + min(excess[face], 0.0)


@njit(cache=True)
def box_distances(points, boxes, candidates):
    """distances_to_boxes on BOX records, compiled."""
    n, k = candidates.shape
    distance, normal = np.empty((n, k)), np.empty((n, k, 3))
    for i in range(n):
        for j in range(k):
            if candidates[i, j] == NO_BOX:
                distance[i, j], normal[i, j] = np.inf, 0.0
            else:
                distance[i, j] = box_distance(points[i], boxes[candidates[i, j]], normal[i, j])
    return distance, normal


def signed_distance_to_boxes(points: np.ndarray, boxes: Boxes, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (N,) from each point to the union of its candidate boxes and the outward
    normal (N, 3) of the nearest surface."""
    distance, normal = distances_to_boxes(points, boxes, candidates)
    best = np.argmin(distance, axis=1)
    rows = np.arange(len(points))
    return distance[rows, best], normal[rows, best]


@njit(cache=True)
def closest_distance(point, boxes, candidates):
    """signed_distance_to_boxes's distance of one point to the union of its `candidates` (a row of
    box indices), compiled."""
    normal = np.empty(3)
    best, first = np.inf, True
    for j in range(len(candidates)):
        if candidates[j] == NO_BOX:
            continue
        distance = box_distance(point, boxes[candidates[j]], normal)
        if first or distance < best or (np.isnan(distance) and not np.isnan(best)):
            best, first = distance, False
    return best


# ---------------------------------------------------------------- spheres in the terrain
def sphere_contacts(centers: np.ndarray, radius: float, boxes: Boxes, candidates: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Indentation (N,) of spheres in the union of their candidate boxes and the contact normal (N, 3).

    A sphere in a concave corner (a block's top against the riser of a higher neighbour) indents
    several boxes at once; a single nearest-surface normal would then jump between them from one
    step to the next. The normal is the indentation-weighted mean of every indented box's normal,
    and the indentation the largest one: both continuous."""
    distance, normal = distances_to_boxes(centers, boxes, candidates)
    indentation = np.maximum(radius - distance, 0.0)
    depth = indentation.max(axis=1, initial=0.0)
    blended = np.einsum("nk,nki->ni", indentation, normal)
    length = np.linalg.norm(blended, axis=1)
    return depth, np.where((length > 0.0)[:, None], blended / np.where(length > 0.0, length, 1.0)[:, None], blended)


@njit(cache=True)
def sphere_contact_arrays(spheres, radius, boxes, candidates):
    """sphere_contacts on BOX records, compiled (callable from other kernels)."""
    n, k = candidates.shape
    depth, blended, normal = np.zeros(n), np.zeros((n, 3)), np.empty(3)
    for i in range(n):
        for j in range(k):
            if candidates[i, j] == NO_BOX:
                continue
            indentation = radius - box_distance(spheres[i], boxes[candidates[i, j]], normal)
            if indentation > 0.0:
                depth[i] = max(depth[i], indentation)
                blended[i] += indentation * normal
        length = math.sqrt(blended[i, 0] ** 2 + blended[i, 1] ** 2 + blended[i, 2] ** 2)
        if length > 0.0:
            blended[i] /= length
    return depth, blended


@njit(cache=True)
def _blocks_around(points, grid):
    candidates = np.empty((len(points), 9), np.int64)
    for i in range(len(points)):
        ix = min(max(int(math.floor((points[i, 0] - grid.x0) / grid.cell)), 0), grid.nx - 1)
        iy = min(max(int(math.floor((points[i, 1] - grid.y0) / grid.cell)), 0), grid.ny - 1)
        k = 0
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                candidates[i, k] = min(max(ix + dx, 0), grid.nx - 1) * grid.ny + min(max(iy + dy, 0), grid.ny - 1)
                k += 1
    return candidates


@njit(cache=True)
def candidates_by_rule(points, rule):
    """Terrain.candidates of (N, 3) `points` by a terrain's `candidate_rule()` (compiled; callable
    from other kernels)."""
    record = the_record(rule)
    if record.kind == BLOCKS_AROUND:
        return _blocks_around(points, record)
    candidates = np.empty((len(points), record.boxes), np.int64)
    for i in range(len(points)):
        for j in range(record.boxes):
            candidates[i, j] = j
    return candidates

