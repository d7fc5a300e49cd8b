"""Ground made of square blocks on a grid: rough ground and height maps."""

from __future__ import annotations

import numpy as np

from testbed.world.config import TerrainConfig
from testbed.world.terrain.base import Terrain
from testbed.world.terrain.geometry import BASE_DEPTH, BLOCKS_AROUND, axis_aligned_boxes, candidate_rule, \
    candidates_by_rule


class GridTerrain(Terrain):
    """Square blocks of side `cell` whose corner [0, 0] is at (x0, y0); `tops[ix, iy]` is the top
    height of the block ix cells along x and iy along y. Block ix * ny + iy is that block's box, so
    the blocks around a point are found by arithmetic (the BLOCKS_AROUND candidate rule). The
    blocks reach down to `bottom` (default: BASE_DEPTH below the lowest top)."""

    def __init__(self, config: TerrainConfig, tops: np.ndarray, x0: float, y0: float, cell: float,
                 bottom: float | None = None):
        self.tops = np.asarray(tops, dtype=float)
        self.nx, self.ny = self.tops.shape
        self.x0, self.y0, self.cell = float(x0), float(y0), float(cell)
        gx, gy = np.meshgrid(x0 + cell * np.arange(self.nx), y0 + cell * np.arange(self.ny), indexing="ij")
        bottom = float(self.tops.min()) - BASE_DEPTH if bottom is None else bottom
        boxes = axis_aligned_boxes(gx.ravel(), gx.ravel() + cell, gy.ravel(), gy.ravel() + cell,
                                   self.tops.ravel(), bottom)
        super().__init__(config, boxes)
        self._grid = candidate_rule(BLOCKS_AROUND, boxes=len(boxes), x0=self.x0, y0=self.y0, cell=self.cell,
                                    nx=self.nx, ny=self.ny)

    def _cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ix = np.clip(np.floor((xy[:, 0] - self.x0) / self.cell).astype(int), 0, self.nx - 1)
        iy = np.clip(np.floor((xy[:, 1] - self.y0) / self.cell).astype(int), 0, self.ny - 1)
        return ix, iy

    def height(self, xy: np.ndarray) -> np.ndarray:
        ix, iy = self._cell(np.atleast_2d(xy))
        return self.tops[ix, iy]

    def candidates(self, points: np.ndarray) -> np.ndarray:
        """The block under each point and its eight neighbours (clipped at the grid's edge)."""
        return candidates_by_rule(np.asarray(points, dtype=float), self._grid)

    def candidate_rule(self) -> np.ndarray | None:
        if type(self).candidates is not GridTerrain.candidates:
            return None
        return self._grid
