"""The Terrain base class, the terrain registry and `make_terrain`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from testbed.model.errors import PluginError
from testbed.model.registry import Registry
from testbed.world.config import TerrainConfig
from testbed.world.terrain.geometry import (EVERY_BOX, Boxes, box_footprints, candidate_rule,
                                            signed_distance_to_boxes, sphere_contacts)

TERRAIN_STREAM = 1  # child index of the run's SeedSequence used for terrain randomness

EDGE, ROUGH_PATCH = "edge", "rough"     # TerrainFeature kinds


class TerrainFeature(NamedTuple):
    """Ground the robot crosses along x, for the metrics: an EDGE at x0 = x1 (a step's or a stair's
    riser, a ramp's gradient change) or a ROUGH_PATCH from x0 to x1 (m, world frame)."""
    kind: str
    x0: float
    x1: float


class Terrain:
    """Base class of every terrain, built-in or a user's plugin: a union of boxes (what DART and
    the compliant contact collide with) with analytic height and normal (what the tests, the
    metrics and the start placement ask).

    A subclass calls `super().__init__(config, boxes)` with the `[terrain]` config section and its
    `Boxes`, implements `height(xy) -> (N,)` and, unless the ground is level, `normal(xy) -> (N, 3)`.
    `from_config(config, rng)` builds it from the run's Config and the terrain's random stream;
    the default calls `cls(config.terrain)`. `check_config(config)` refuses (ConfigError) a run
    config the terrain cannot be built or walked on from; the config calls it when it is loaded.
    """

    name = "terrain"

    def __init__(self, config: TerrainConfig, boxes: Boxes):
        self.config = config
        self.boxes = boxes
        self._every_box = np.arange(len(boxes))

    @classmethod
    def from_config(cls, config, rng: np.random.Generator) -> "Terrain":
        return cls(config.terrain)

    @classmethod
    def check_config(cls, config) -> None:
        """Nothing to check beyond the [terrain] section's own ranges."""

    def height(self, xy: np.ndarray) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} must implement height(xy)")

    def normal(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        return np.tile([0.0, 0.0, 1.0], (len(xy), 1))

    def features(self) -> tuple[TerrainFeature, ...]:
        """The edges and rough patches the robot crosses walking along +x; none by default."""
        return ()

    def footprint(self) -> tuple[float, float, float, float]:
        """x_min, x_max, y_min, y_max of the built terrain: the boxes' corners seen from above."""
        footprints = box_footprints(self.boxes)
        return (float(footprints[:, 0].min()), float(footprints[:, 1].max()), float(footprints[:, 2].min()),
                float(footprints[:, 3].max()))

    def candidates(self, points: np.ndarray) -> np.ndarray:
        """(N, K) indices of the boxes that may hold the surface nearest each point (NO_BOX pads)."""
        return np.broadcast_to(self._every_box, (len(points), len(self._every_box)))

    def candidate_rule(self) -> np.ndarray | None:
        """`candidates` for compiled code: a one-element CANDIDATE_RULE array for
        `candidates_by_rule`, which gives the same boxes in the same order; None for a subclass
        with candidates of its own."""
        if type(self).candidates is not Terrain.candidates:
            return None
        return candidate_rule(EVERY_BOX, boxes=len(self.boxes))

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        points = np.atleast_2d(np.asarray(points, dtype=float))
        return signed_distance_to_boxes(points, self.boxes, self.candidates(points))

    def sphere_contacts(self, centers: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Indentation (N,) of spheres in the terrain and the contact normal (N, 3): `sphere_contacts`."""
        centers = np.atleast_2d(np.asarray(centers, dtype=float))
        return sphere_contacts(centers, float(radius), self.boxes, self.candidates(centers))


TERRAINS = Registry.of_subclasses("terrain", "terrains", Terrain)


def check_terrain_config(config) -> None:
    """The run's terrain's `check_config` on the whole config, for a registered terrain (a plugin
    named MODULE:CLASS is checked when it is built)."""
    if TERRAINS.is_known(config.run.terrain):
        TERRAINS.resolve(config.run.terrain).check_config(config)


def make_terrain(spec: str, config, rng: np.random.Generator) -> Terrain:
    """The terrain named by `spec`: `cls.check_config(config)`, then `cls.from_config(config, rng)`
    with the run's Config and the terrain's random stream."""
    TERRAINS.resolve(spec).check_config(config)
    terrain = TERRAINS.build(spec, config, rng)
    if not isinstance(terrain, Terrain) or len(terrain.boxes) == 0:
        raise PluginError(f"terrain '{spec}' built no boxes")
    return terrain
