"""Courses: ground built from segments laid along +x (`terrain.course`), with real gradient changes.

The course is cut into pieces along x, each spanning the extent's width: level pieces (flat
ground, stair treads, the ground before and after the course), ramps (one rotated box whose top
face joins the level before it to the level after it) and rough patches (blocks around the
level). A step is no piece of its own: it changes the level the next piece starts at.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from testbed.model.errors import ConfigError
from testbed.model.validation import require
from testbed.world.config import CourseSegment, TerrainConfig
from testbed.world.terrain.base import EDGE, ROUGH_PATCH, Terrain, TerrainFeature
from testbed.world.terrain.bins import BoxBins
from testbed.world.terrain.geometry import BASE_DEPTH, EVERY_BOX, MAX_BLOCKS, Boxes, axis_aligned_boxes, candidate_rule

LEVEL, RAMP, ROUGH = "level", "ramp", "rough"
# m beyond a foot's diameter within which boxes are a foot's candidates: more than the support
# check's ground tolerance (1 mm).
CANDIDATE_REACH = 0.01


@dataclass(frozen=True)
class Piece:
    """Ground between x0 and x1 whose surface runs from z0 at x0 to z1 at x1 (a ramp), or stays at
    z0 (level), or has block tops `tops` (nx, ny) of side `cell` around z0 (rough)."""
    kind: str
    x0: float
    x1: float
    z0: float
    z1: float
    cell: float = 0.0
    tops: np.ndarray | None = None

    @property
    def angle(self) -> float:
        return math.atan2(self.z1 - self.z0, self.x1 - self.x0)


def course_pieces(config: TerrainConfig, rng: np.random.Generator) -> list[Piece]:
    """The pieces of `config.course` from course_start, with level ground before it from the
    extent's x_min and after it to x_max; rough tops drawn from `rng` segment by segment."""
    x_min, x_max, y_min, y_max = config.extent
    x, level = config.course_start, 0.0
    pieces = [Piece(LEVEL, x_min, x, 0.0, 0.0)] if x > x_min else []
    for segment in config.course:
        if segment.kind == "step":
            level += segment.height
        elif segment.kind == "stairs":
            for _ in range(segment.steps):
                level += segment.rise
                pieces.append(Piece(LEVEL, x, x + segment.tread, level, level))
                x += segment.tread
        elif segment.kind == "rough":
            pieces.append(_rough_piece(segment, x, level, y_max - y_min, rng))
            x += segment.length
        else:
            end_level = level + segment.climb
            pieces.append(Piece(RAMP if segment.kind == "ramp" else LEVEL, x, x + segment.length, level, end_level))
            x, level = x + segment.length, end_level
    if x < x_max:
        pieces.append(Piece(LEVEL, x, x_max, level, level))
    return pieces


def _rough_piece(segment: CourseSegment, x: float, level: float, width: float, rng: np.random.Generator) -> Piece:
    shape = (math.ceil(segment.length / segment.cell - 1e-9), math.ceil(width / segment.cell - 1e-9))
    tops = level + rng.uniform(-segment.amplitude, segment.amplitude, shape)
    return Piece(ROUGH, x, x + segment.length, level, level, segment.cell, tops)


def piece_boxes(piece: Piece, y0: float, y1: float, bottom: float) -> Boxes:
    """The boxes of one piece over [y0, y1], reaching down to `bottom` (a ramp: its rotated box
    and a level fill below it)."""
    if piece.kind == LEVEL:
        return axis_aligned_boxes(piece.x0, piece.x1, y0, y1, np.array([piece.z0]), bottom)
    if piece.kind == ROUGH:
        nx, ny = piece.tops.shape
        xs = np.minimum(piece.x0 + piece.cell * np.arange(nx + 1), piece.x1)
        ys = np.minimum(y0 + piece.cell * np.arange(ny + 1), y1)
        gx0, gy0 = np.meshgrid(xs[:-1], ys[:-1], indexing="ij")
        gx1, gy1 = np.meshgrid(xs[1:], ys[1:], indexing="ij")
        return axis_aligned_boxes(gx0.ravel(), gx1.ravel(), gy0.ravel(), gy1.ravel(), piece.tops.ravel(), bottom)
    return _joined([_ramp_box(piece, y0, y1, bottom),
                    axis_aligned_boxes(piece.x0, piece.x1, y0, y1, np.array([min(piece.z0, piece.z1)]), bottom)])


def _ramp_box(piece: Piece, y0: float, y1: float, bottom: float) -> Boxes:
    """The rotated box whose top face is the ramp. Its ends are square to the slope, so each leaves
    a wedge open below one end of the top face: the level fill box under the ramp (down to its
    lower end's level) closes it."""
    c, s = math.cos(piece.angle), math.sin(piece.angle)
    rotation = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # R_y(-angle): z onto the normal
    thickness = max(piece.z0, piece.z1) - bottom
    half = np.array([(piece.x1 - piece.x0) / (2 * c), (y1 - y0) / 2, thickness / 2])
    top_middle = np.array([(piece.x0 + piece.x1) / 2, (y0 + y1) / 2, (piece.z0 + piece.z1) / 2])
    return Boxes((top_middle - half[2] * rotation[:, 2])[None], half[None], rotation[None])


def _check_walkable(segment: CourseSegment, where: str, foot_radius: float, limits) -> None:
    """Treads and blocks at least as wide as the foot; rises, drops and rough amplitudes within
    `limits` (the run's `Config.climb_limits()`: up, down, rough_amplitude in m; None: not checked)."""
    if segment.kind == "stairs":
        require(segment.tread >= 2 * foot_radius, f"{where}: tread {segment.tread} m is narrower than the foot "
                                                  f"({2 * foot_radius} m, robot.foot_radius x 2)")
    if segment.kind == "rough":
        require(segment.cell >= 2 * foot_radius, f"{where}: cell {segment.cell} m is smaller than the foot "
                                                 f"({2 * foot_radius} m, robot.foot_radius x 2)")
    if limits is None:
        return
    if segment.kind in ("step", "stairs"):
        rise = segment.height if segment.kind == "step" else segment.rise
        limit = limits.up if rise > 0 else limits.down
        require(abs(rise) <= limit + 1e-12,
                f"{where}: a {abs(rise) * 100:.1f} cm {'rise' if rise > 0 else 'drop'} is more than the legs can "
                f"{'clear' if rise > 0 else 'reach down'}: at most {limit * 100:.1f} cm (posture.max_swing_height "
                f"less posture.step_clearance up, posture.search_depth down)")
    if segment.kind == "rough":
        require(segment.amplitude <= limits.rough_amplitude + 1e-12,
                f"{where}: amplitude {segment.amplitude * 100:.1f} cm is more than the legs can clear or reach "
                f"down: at most {limits.rough_amplitude * 100:.1f} cm")


def _joined(parts: list[Boxes]) -> Boxes:
    return Boxes(*(np.concatenate([getattr(part, name) for part in parts])
                   for name in ("centers", "half_extents", "rotations")))


class CourseTerrain(Terrain):
    """`terrain.course` laid along +x from `terrain.course_start` across the extent's width."""

    name = "course"

    def __init__(self, config: TerrainConfig, rng: np.random.Generator, foot_radius: float):
        _, _, y0, y1 = config.extent
        self.pieces = course_pieces(config, rng)
        self.starts = np.array([piece.x0 for piece in self.pieces])
        lowest = min(min(piece.z0, piece.z1) if piece.tops is None else float(piece.tops.min())
                     for piece in self.pieces)
        super().__init__(config, _joined([piece_boxes(piece, y0, y1, lowest - BASE_DEPTH) for piece in self.pieces]))
        rough = [piece.cell for piece in self.pieces if piece.kind == ROUGH]
        # Few boxes: every box is a candidate. Rough patches: the boxes near each point, by bins.
        self._bins = BoxBins(self.boxes, min(rough), 2 * foot_radius + CANDIDATE_REACH) if rough else None

    @classmethod
    def from_config(cls, config, rng: np.random.Generator) -> "CourseTerrain":
        return cls(config.terrain, rng, config.robot.foot_radius)

    @classmethod
    def check_config(cls, config) -> None:
        """The course fits the extent, and the robot can walk on each segment."""
        terrain = config.terrain
        x_min, x_max, y_min, y_max = terrain.extent
        require(len(terrain.course) > 0, "terrain.course is empty: give it segments "
                                         "(e.g. course = [{ kind = \"flat\", length = 1.0 }])")
        require(x_min <= terrain.course_start < x_max,
                f"terrain.course_start {terrain.course_start} m lies outside terrain.extent's x range "
                f"[{x_min}, {x_max})")
        require(terrain.course_end <= x_max + 1e-9,
                f"terrain.course ends at x = {terrain.course_end:.3f} m, beyond terrain.extent's x_max {x_max} m")
        for index, segment in enumerate(terrain.course):
            _check_walkable(segment, f"terrain.course[{index}] ({segment.kind})", config.robot.foot_radius,
                            config.climb_limits())
        blocks = sum(math.ceil(segment.length / segment.cell) * math.ceil((y_max - y_min) / segment.cell)
                     for segment in terrain.course if segment.kind == "rough")
        if blocks > MAX_BLOCKS:
            raise ConfigError(f"terrain.course's rough segments make {blocks} blocks, more than {MAX_BLOCKS}")

    def features(self) -> tuple[TerrainFeature, ...]:
        """Each rough patch, and each edge between two other pieces: a change of level (a step, a
        stair's riser) or of gradient (a ramp's ends)."""
        features = [TerrainFeature(ROUGH_PATCH, piece.x0, piece.x1) for piece in self.pieces if piece.kind == ROUGH]
        for before, after in zip(self.pieces, self.pieces[1:]):
            if ROUGH not in (before.kind, after.kind) and (
                    not math.isclose(before.z1, after.z0, abs_tol=1e-9)
                    or not math.isclose(before.angle, after.angle, abs_tol=1e-9)):
                features.append(TerrainFeature(EDGE, after.x0, after.x0))
        return tuple(sorted(features, key=lambda feature: feature.x0))

    def _piece_of(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.starts, x, side="right") - 1, 0, len(self.pieces) - 1)

    def height(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        _, _, y_min, _ = self.config.extent
        heights = np.empty(len(xy))
        pieces = self._piece_of(xy[:, 0])
        for index in np.unique(pieces):
            piece, rows = self.pieces[index], pieces == index
            x, y = xy[rows, 0], xy[rows, 1]
            if piece.kind == ROUGH:
                nx, ny = piece.tops.shape
                ix = np.clip(np.floor((x - piece.x0) / piece.cell).astype(int), 0, nx - 1)
                iy = np.clip(np.floor((y - y_min) / piece.cell).astype(int), 0, ny - 1)
                heights[rows] = piece.tops[ix, iy]
            else:
                heights[rows] = piece.z0 + (np.clip(x, piece.x0, piece.x1) - piece.x0) * math.tan(piece.angle)
        return heights

    def normal(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        angles = np.array([piece.angle if piece.kind == RAMP else 0.0 for piece in self.pieces])[
            self._piece_of(xy[:, 0])]
        return np.column_stack([-np.sin(angles), np.zeros(len(xy)), np.cos(angles)])

    def candidates(self, points: np.ndarray) -> np.ndarray:
        """Every box, or with rough patches the boxes whose footprint lies near each point."""
        if self._bins is None:
            return super().candidates(points)
        return self._bins.near(np.asarray(points, dtype=float))

    def candidate_rule(self) -> np.ndarray | None:
        if self._bins is not None or type(self).candidates is not CourseTerrain.candidates:
            return None
        return candidate_rule(EVERY_BOX, boxes=len(self.boxes))
