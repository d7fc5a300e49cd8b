"""The preset terrains: flat, slope, step and rough ground, each uniform over `terrain.extent`."""

from __future__ import annotations

import numpy as np

from testbed.model.errors import ConfigError
from testbed.model.validation import require
from testbed.world.config import TerrainConfig
from testbed.world.terrain.base import EDGE, Terrain, TerrainFeature
from testbed.world.terrain.geometry import BASE_DEPTH, MAX_BLOCKS, Boxes, axis_aligned_boxes
from testbed.world.terrain.grid import GridTerrain


class FlatTerrain(Terrain):
    name = "flat"

    def __init__(self, config: TerrainConfig):
        x0, x1, y0, y1 = config.extent
        super().__init__(config, axis_aligned_boxes(x0, x1, y0, y1, np.zeros(1), -BASE_DEPTH))

    def height(self, xy: np.ndarray) -> np.ndarray:
        return np.zeros(len(np.atleast_2d(xy)))


class SlopeTerrain(Terrain):
    """An inclined plane through the origin, z = x tan(slope): uphill along +x for a positive slope."""

    name = "slope"

    def __init__(self, config: TerrainConfig):
        self.angle = np.radians(config.slope_deg)
        x0, x1, y0, y1 = config.extent
        c, s = np.cos(self.angle), np.sin(self.angle)
        rotation = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # R_y(-angle): z onto the normal
        x_mid, y_mid = (x0 + x1) / 2, (y0 + y1) / 2
        half = np.array([(x1 - x0) / (2 * c), (y1 - y0) / 2, BASE_DEPTH / 2])
        top_mid = np.array([x_mid, y_mid, x_mid * np.tan(self.angle)])
        center = top_mid - half[2] * rotation[:, 2]
        super().__init__(config, Boxes(center[None], half[None], rotation[None]))

    def height(self, xy: np.ndarray) -> np.ndarray:
        return np.atleast_2d(xy)[:, 0] * np.tan(self.angle)

    def normal(self, xy: np.ndarray) -> np.ndarray:
        n = np.array([-np.sin(self.angle), 0.0, np.cos(self.angle)])
        return np.tile(n, (len(np.atleast_2d(xy)), 1))


class StepTerrain(Terrain):
    """The paper's Figure 8: level ground at z = 0 up to x = step_edge_x, then z = step_height."""

    name = "step"

    def __init__(self, config: TerrainConfig):
        x0, x1, y0, y1 = config.extent
        edge, rise = config.step_edge_x, config.step_height
        if not x0 < edge < x1:
            raise ConfigError(f"terrain.step_edge_x {edge} must lie inside the terrain extent ({x0}, {x1})")
        bottom = min(0.0, rise) - BASE_DEPTH
        boxes = axis_aligned_boxes([x0, edge], [edge, x1], [y0, y0], [y1, y1], np.array([0.0, rise]), bottom)
        super().__init__(config, boxes)

    def height(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        return np.where(xy[:, 0] < self.config.step_edge_x, 0.0, self.config.step_height)

    def features(self) -> tuple[TerrainFeature, ...]:
        return (TerrainFeature(EDGE, self.config.step_edge_x, self.config.step_edge_x),)


class RoughTerrain(GridTerrain):
    """Square blocks of side rough_cell over the extent (rounded up to whole blocks) with top
    heights uniform in +-rough_amplitude; blocks whose centre lies within flat_start_radius of the
    origin are level."""

    name = "rough"

    def __init__(self, config: TerrainConfig, rng: np.random.Generator):
        x0, _, y0, _ = config.extent
        cell = config.rough_cell
        nx, ny = rough_grid_shape(config)
        tops = rng.uniform(-config.rough_amplitude, config.rough_amplitude, (nx, ny))
        gx, gy = np.meshgrid(x0 + cell * np.arange(nx), y0 + cell * np.arange(ny), indexing="ij")
        tops[np.hypot(gx + cell / 2, gy + cell / 2) < config.flat_start_radius] = 0.0
        super().__init__(config, tops, x0, y0, cell, bottom=-config.rough_amplitude - BASE_DEPTH)

    @classmethod
    def check_config(cls, config) -> None:
        """Only rough ground builds blocks over the whole extent: the other presets build a few
        boxes whatever its size."""
        nx, ny = rough_grid_shape(config.terrain)
        blocks = nx * ny
        require(blocks <= MAX_BLOCKS, f"terrain.extent / rough_cell gives {blocks} blocks, more than {MAX_BLOCKS}")

    @classmethod
    def from_config(cls, config, rng: np.random.Generator) -> "RoughTerrain":
        return cls(config.terrain, rng)


def rough_grid_shape(config: TerrainConfig) -> tuple[int, int]:
    """(cells along x, cells along y) of rough ground's blocks over `terrain.extent`."""
    x0, x1, y0, y1 = config.extent
    return int(np.ceil((x1 - x0) / config.rough_cell)), int(np.ceil((y1 - y0) / config.rough_cell))
