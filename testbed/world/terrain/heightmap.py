"""Height maps: `terrain.heightmap`, one block per cell of a 2-D array of heights."""

from __future__ import annotations

import numpy as np

from testbed.model.validation import require
from testbed.world.config import TerrainConfig
from testbed.world.terrain.grid import GridTerrain


class HeightmapTerrain(GridTerrain):
    """The map's cell [row, column] is a block of side heightmap_cell with its top at that height,
    `column` cells along x and `row` along y from the map's corner (`heightmap_origin`, or the map
    centred on the robot's start). The built terrain is the map: nothing around it."""

    name = "heightmap"

    def __init__(self, config: TerrainConfig):
        heights = config.heightmap_heights()
        x0, y0 = config.heightmap_corner()
        super().__init__(config, heights.T, x0, y0, config.heightmap_cell)

    @property
    def heights(self) -> np.ndarray:
        """The map as read: rows along y, columns along x, m."""
        return self.tops.T

    @classmethod
    def check_config(cls, config) -> None:
        terrain, robot = config.terrain, config.robot
        require(bool(terrain.heightmap), "terrain.heightmap names no file: give a .npy or 16-bit .png height map")
        cell, foot = terrain.heightmap_cell, robot.foot_radius
        require(cell >= 2 * foot, f"terrain.heightmap_cell {cell} m is smaller than the foot "
                                  f"({2 * foot} m, robot.foot_radius x 2)")
        heights = terrain.heightmap_heights()
        x0, y0 = terrain.heightmap_corner()
        x1, y1 = x0 + heights.shape[1] * cell, y0 + heights.shape[0] * cell
        reach = max(robot.leg_base_distance) + robot.stance_radius + foot
        require(x0 <= -reach and x1 >= reach and y0 <= -reach and y1 >= reach,
                f"terrain.heightmap covers x [{x0:.3f}, {x1:.3f}], y [{y0:.3f}, {y1:.3f}] m: the robot's feet at "
                f"its start need [{-reach:.3f}, {reach:.3f}] m around the origin")
        limits = config.climb_limits()
        if limits is None:
            return
        jump = max(np.abs(np.diff(heights, axis=0)).max(), np.abs(np.diff(heights, axis=1)).max())
        limit = min(limits.up, limits.down)
        require(jump <= limit + 1e-12, f"terrain.heightmap has a {jump * 100:.1f} cm step between neighbouring "
                                       f"cells, more than the legs can clear or reach down: at most "
                                       f"{limit * 100:.1f} cm")
