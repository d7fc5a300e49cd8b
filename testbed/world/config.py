"""The world's config sections: `[terrain]` and `[contact]`."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from testbed.model.validation import finite, positive, require
from testbed.world.heightmaps import read_heightmap

# The parameters of each kind of course segment; the others keep their default (0).
SEGMENT_KEYS = {"flat": ("length",), "ramp": ("length", "angle_deg"), "step": ("height",),
                "stairs": ("steps", "rise", "tread"), "rough": ("length", "amplitude", "cell")}
MAX_STEP = 0.2          # m, the largest single rise or drop of a step or stair
MAX_RAMP_DEG = 45.0


@dataclass(frozen=True)
class CourseSegment:
    """One table of `terrain.course`: a piece of ground along +x, lengths horizontal, in m.
    flat: `length`; ramp: `length`, `angle_deg` (positive uphill); step: `height` (signed, no
    length); stairs: `steps` treads of `tread` each `rise` (signed) above the one before; rough:
    `length` of blocks of side `cell`, tops uniform in +-`amplitude` around the level."""
    kind: str
    length: float = 0.0
    angle_deg: float = 0.0
    height: float = 0.0
    steps: int = 0
    rise: float = 0.0
    tread: float = 0.0
    amplitude: float = 0.0
    cell: float = 0.0

    @property
    def run(self) -> float:
        """Its length along x."""
        return self.steps * self.tread if self.kind == "stairs" else self.length

    @property
    def climb(self) -> float:
        """The level after it minus the level before it."""
        if self.kind == "ramp":
            return self.length * math.tan(math.radians(self.angle_deg))
        return {"step": self.height, "stairs": self.steps * self.rise}.get(self.kind, 0.0)

    def check(self, where: str) -> None:
        require(self.kind in SEGMENT_KEYS, f"{where}: unknown kind '{self.kind}' (choose from "
                                           f"{', '.join(SEGMENT_KEYS)})")
        where = f"{where} ({self.kind})"
        keys = SEGMENT_KEYS[self.kind]
        for field in fields(self):
            if field.name != "kind" and field.name not in keys:
                require(getattr(self, field.name) == field.default,
                        f"{where} takes {', '.join(keys)}, not {field.name}")
        values = {key: getattr(self, key) for key in keys}
        finite(where, *values.values())
        if "length" in keys:
            positive(f"{where} length", self.length)
        if self.kind == "ramp":
            require(0 < abs(self.angle_deg) <= MAX_RAMP_DEG,
                    f"{where} angle_deg must be non-zero and within +-{MAX_RAMP_DEG:g}, got {self.angle_deg}")
        if self.kind in ("step", "stairs"):
            rise = self.height if self.kind == "step" else self.rise
            require(0 < abs(rise) <= MAX_STEP,
                    f"{where} {'height' if self.kind == 'step' else 'rise'} must be non-zero and within "
                    f"+-{MAX_STEP:g} m, got {rise}")
        if self.kind == "stairs":
            require(1 <= self.steps <= 100, f"{where} steps must lie in [1, 100], got {self.steps}")
            positive(f"{where} tread", self.tread)
        if self.kind == "rough":
            require(0 < self.amplitude <= 0.1, f"{where} amplitude must lie in (0, 0.1] m, got {self.amplitude}")
            require(0.02 <= self.cell <= 2.0, f"{where} cell must lie in [0.02, 2] m, got {self.cell}")


@dataclass(frozen=True)
class TerrainConfig:
    slope_deg: float
    step_height: float
    step_edge_x: float
    rough_amplitude: float
    rough_cell: float
    extent: tuple[float, ...]
    flat_start_radius: float
    course_start: float
    course: tuple[CourseSegment, ...]
    heightmap: str
    heightmap_scale: float
    heightmap_cell: float
    heightmap_origin: tuple[float, ...]

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
        require(math.isfinite(self.flat_start_radius) and self.flat_start_radius >= 0,
                 f"terrain.flat_start_radius must be >= 0, got {self.flat_start_radius}")
        finite("terrain.course_start", self.course_start)
        for index, segment in enumerate(self.course):
            segment.check(f"terrain.course[{index}]")
        positive("terrain.heightmap_scale", self.heightmap_scale)
        positive("terrain.heightmap_cell", self.heightmap_cell)
        require(len(self.heightmap_origin) in (0, 2),
                 "terrain.heightmap_origin needs 2 numbers (x, y of the corner of cell [0, 0]) or none "
                 "(the map centred on the robot's start)")
        finite("terrain.heightmap_origin", *self.heightmap_origin)
        if self.heightmap:
            read_heightmap(self.heightmap, self.heightmap_scale)

    @property
    def course_end(self) -> float:
        """x where the course's last segment ends."""
        return self.course_start + sum(segment.run for segment in self.course)

    def heightmap_heights(self):
        """The height map's heights in m (rows along y, columns along x), read from its file."""
        return read_heightmap(self.heightmap, self.heightmap_scale)

    def heightmap_corner(self) -> tuple[float, float]:
        """x, y of the corner of cell [0, 0]: heightmap_origin, or the map centred on the origin."""
        if self.heightmap_origin:
            return float(self.heightmap_origin[0]), float(self.heightmap_origin[1])
        rows, columns = self.heightmap_heights().shape
        return -columns * self.heightmap_cell / 2, -rows * self.heightmap_cell / 2

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
