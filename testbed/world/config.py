"""The world's config sections: `[terrain]` and `[contact]`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from testbed.model.validation import finite, positive, require

@dataclass(frozen=True)
class TerrainConfig:
    slope_deg: float
    step_height: float
    step_edge_x: float
    rough_amplitude: float
    rough_cell: float
    extent: tuple[float, ...]
    flat_start_radius: float

    def __post_init__(self) -> None:
        require(math.isfinite(self.slope_deg) and abs(self.slope_deg) <= 45,
                 f"terrain.slope_deg must lie in [-45, 45], got {self.slope_deg}")
        require(math.isfinite(self.step_height) and abs(self.step_height) <= 0.2,
                 f"terrain.step_height must lie in [-0.2, 0.2] m, got {self.step_height}")
        finite("terrain.step_edge_x", self.step_edge_x)
        require(math.isfinite(self.rough_amplitude) and 0 <= self.rough_amplitude <= 0.1,
                 f"terrain.rough_amplitude must lie in [0, 0.1] m, got {self.rough_amplitude}")
        require(math.isfinite(self.rough_cell) and 0.02 <= self.rough_cell <= 2.0,
                 f"terrain.rough_cell must lie in [0.02, 2] m, got {self.rough_cell}")
        require(len(self.extent) == 4, "terrain.extent needs 4 numbers: x_min x_max y_min y_max")
        finite("terrain.extent", *self.extent)
        x_min, x_max, y_min, y_max = self.extent
        require(x_min < 0 < x_max and y_min < 0 < y_max, "terrain.extent must contain the origin")
        require((x_max - x_min) * (y_max - y_min) / self.rough_cell**2 <= 20000,
                 "terrain.extent / rough_cell gives more than 20000 blocks")
        require(math.isfinite(self.flat_start_radius) and self.flat_start_radius >= 0,
                 f"terrain.flat_start_radius must be >= 0, got {self.flat_start_radius}")

@dataclass(frozen=True)
class ContactConfig:
    friction: float
    stiffness: float
    exponent: float
    damping: float
    tangential_stiffness: float
    tangential_damping: float

    def __post_init__(self) -> None:
        require(math.isfinite(self.friction) and 0 <= self.friction <= 5,
                 f"contact.friction must lie in [0, 5], got {self.friction}")
        positive("contact.stiffness", self.stiffness)
        require(math.isfinite(self.exponent) and 1.0 <= self.exponent <= 2.0,
                 f"contact.exponent must lie in [1, 2], got {self.exponent}")
        require(math.isfinite(self.damping) and self.damping >= 0, f"contact.damping must be >= 0, got {self.damping}")
        positive("contact.tangential_stiffness", self.tangential_stiffness)
        require(math.isfinite(self.tangential_damping) and self.tangential_damping >= 0,
                 f"contact.tangential_damping must be >= 0, got {self.tangential_damping}")
