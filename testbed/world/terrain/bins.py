"""The boxes near a point, looked up in a table of square bins: for terrains whose boxes lie on no
single grid (a course with rough patches)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.world.terrain.geometry import NO_BOX, Boxes, box_footprints


class BoxBins:
    """Square bins of side `size` over the boxes' footprint; each lists (ascending, NO_BOX after)
    the boxes whose footprint, widened by `margin`, overlaps it. A point's candidates are its
    bin's list (points off the table take the nearest bin's): every box within `margin` of the
    point horizontally."""

    def __init__(self, boxes: Boxes, size: float, margin: float):
        footprints = box_footprints(boxes)
        self.x0, self.y0 = float(footprints[:, 0].min()), float(footprints[:, 2].min())
        self.size = float(size)
        self.nx = math.ceil((footprints[:, 1].max() - self.x0) / size)
        self.ny = math.ceil((footprints[:, 3].max() - self.y0) / size)
        self.table = self._table(footprints, margin)

    def _bin_range(self, low: float, high: float, origin: float, count: int) -> range:
        first = min(max(math.floor((low - origin) / self.size), 0), count - 1)
        last = min(max(math.floor((high - origin) / self.size), 0), count - 1)
        return range(first, last + 1)

    def _table(self, footprints: np.ndarray, margin: float) -> np.ndarray:
        bins, owners = [], []
        for box, (x_low, x_high, y_low, y_high) in enumerate(footprints):
            xs = self._bin_range(x_low - margin, x_high + margin, self.x0, self.nx)
            ys = self._bin_range(y_low - margin, y_high + margin, self.y0, self.ny)
            flat = (np.asarray(xs)[:, None] * self.ny + np.asarray(ys)[None, :]).ravel()
            bins.append(flat)
            owners.append(np.full(len(flat), box))
        bins, owners = np.concatenate(bins), np.concatenate(owners)
        order = np.lexsort((owners, bins))
        bins, owners = bins[order], owners[order]
        counts = np.bincount(bins, minlength=self.nx * self.ny)
        first_of_bin = np.concatenate([[0], np.cumsum(counts)[:-1]])
        table = np.full((self.nx * self.ny, max(int(counts.max()), 1)), NO_BOX, dtype=np.int64)
        table[bins, np.arange(len(bins)) - first_of_bin[bins]] = owners
        return table

    def near(self, points: np.ndarray) -> np.ndarray:
        """(N, K) candidate boxes of (N, >= 2) points: `near_readable`, compiled (the compliant
        contact and the support check ask it at every physics step)."""
        return binned_candidates(np.ascontiguousarray(points, dtype=np.float64), self.x0, self.y0, self.size,
                                 self.nx, self.ny, self.table)

    def near_readable(self, points: np.ndarray) -> np.ndarray:
        """(N, K) candidate boxes of (N, >= 2) points."""
        ix = np.clip(np.floor((points[:, 0] - self.x0) / self.size).astype(np.int64), 0, self.nx - 1)
        iy = np.clip(np.floor((points[:, 1] - self.y0) / self.size).astype(np.int64), 0, self.ny - 1)
        return self.table[ix * self.ny + iy]


@njit(cache=True)
def binned_candidates(points, x0, y0, size, nx, ny, table):
    """BoxBins.near_readable: each point's row of `table`, the bins being `size` squares from
    (x0, y0), nx along x by ny along y (points off the table take the nearest bin's)."""
    candidates = np.empty((len(points), table.shape[1]), np.int64)
    for i in range(len(points)):
        candidates[i] = table[_bin_index(points[i, 0], x0, size, nx) * ny + _bin_index(points[i, 1], y0, size, ny)]
    return candidates


@njit(cache=True)
def _bin_index(coordinate, origin, size, count):
    """The bin along one axis, clipped to the table (a NaN coordinate: the first)."""
    position = (coordinate - origin) / size         # in bins
    if not position >= 1.0:
        return 0
    if position >= count - 1:
        return count - 1
    return int(position)
