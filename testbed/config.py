"""One configuration for a run: frozen dataclasses built from `defaults.toml` plus user overrides.

The dataclasses are the schema (names, types, valid ranges); `defaults.toml` holds every default
value. A user's TOML file is merged over the defaults, unknown keys are rejected, and the fully
resolved config is stored with each run (`Config.to_dict`, `Config.to_toml`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import tomli_w

from estimators.config import EstimatorsConfig
from sensors.config import SensorsConfig
from testbed.errors import ConfigError
from testbed.validation import finite, non_negative, positive, require

TERRAINS = ("flat", "slope", "step", "rough")
CONTACTS = ("compliant", "dart")
GAITS = ("stand", "tripod", "ripple", "wave")   # testbed.gait.GAIT_TABLE holds the walking ones
ESTIMATORS = ("none", "ekf", "ukf", "complementary", "madgwick", "mahony", "vqf")   # estimators.registry
CONTROLLERS = ("none", "posture")   # posture: testbed.posture


@dataclass(frozen=True)
class RunConfig:
    terrain: str
    contact: str
    gait: str
    estimator: str
    controller: str
    duration: float
    seed: int
    time_step: float
    gravity: float

    def __post_init__(self) -> None:
        require(self.terrain in TERRAINS, f"unknown terrain '{self.terrain}' (choose from {', '.join(TERRAINS)})")
        require(self.contact in CONTACTS, f"unknown contact model '{self.contact}' (choose from {', '.join(CONTACTS)})")
        require(self.gait in GAITS, f"unknown gait '{self.gait}' (choose from {', '.join(GAITS)})")
        require(self.estimator in ESTIMATORS,
                 f"unknown estimator '{self.estimator}' (choose from {', '.join(ESTIMATORS)})")
        require(self.controller in CONTROLLERS,
                 f"unknown controller '{self.controller}' (choose from {', '.join(CONTROLLERS)})")
        require(self.controller != "posture" or self.estimator != "none",
                 "controller 'posture' needs an attitude estimator (--estimator ekf, for example)")
        positive("run.duration", self.duration)
        require(self.duration <= 24 * 3600, f"run.duration {self.duration} s is longer than a day")
        require(0 <= self.seed < 2**63, f"run.seed must be a non-negative integer, got {self.seed}")
        positive("run.time_step", self.time_step)
        require(self.time_step <= 0.01, f"run.time_step {self.time_step} s is too coarse for contact (max 0.01)")
        positive("run.gravity", self.gravity)


@dataclass(frozen=True)
class RobotConfig:
    body_mass: float
    body_size: tuple[float, ...]
    leg_base_angle_deg: tuple[float, ...]
    leg_base_distance: tuple[float, ...]
    coxa_mass: float
    coxa_size: tuple[float, ...]
    femur_length: float
    femur_mass: float
    femur_section: tuple[float, ...]
    tibia_length: float
    tibia_mass: float
    tibia_radius: float
    foot_radius: float
    joint_lower_deg: tuple[float, ...]
    joint_upper_deg: tuple[float, ...]
    servo_torque_limit: float
    servo_speed_limit: float
    servo_gain: float
    stance_radius: float
    stance_height: float

    def __post_init__(self) -> None:
        require(len(self.body_size) == 3, "robot.body_size needs 3 numbers")
        require(len(self.coxa_size) == 3, "robot.coxa_size needs 3 numbers")
        require(len(self.femur_section) == 2, "robot.femur_section needs 2 numbers")
        require(len(self.leg_base_angle_deg) == 6, "robot.leg_base_angle_deg needs 6 numbers (one per leg)")
        require(len(self.leg_base_distance) == 6, "robot.leg_base_distance needs 6 numbers (one per leg)")
        require(len(self.joint_lower_deg) == 3 and len(self.joint_upper_deg) == 3,
                 "robot.joint_lower_deg and joint_upper_deg need 3 numbers (coxa, femur, tibia)")
        positive("robot sizes and masses", self.body_mass, *self.body_size, self.coxa_mass, *self.coxa_size,
                         self.femur_length, self.femur_mass, *self.femur_section, self.tibia_length,
                         self.tibia_mass, self.tibia_radius, self.foot_radius, *self.leg_base_distance)
        positive("robot servo limits", self.servo_torque_limit, self.servo_speed_limit, self.servo_gain)
        positive("robot stance", self.stance_radius, self.stance_height)
        finite("robot.leg_base_angle_deg", *self.leg_base_angle_deg)
        for lower, upper in zip(self.joint_lower_deg, self.joint_upper_deg):
            require(math.isfinite(lower) and math.isfinite(upper) and -180 <= lower < upper <= 180,
                     f"robot joint limits must satisfy -180 <= lower < upper <= 180, got [{lower}, {upper}]")
        require(self.stance_height > self.foot_radius,
                 "robot.stance_height must exceed robot.foot_radius")


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


@dataclass(frozen=True)
class GaitConfig:
    speed: float
    lateral_speed: float
    turn_rate: float
    target: tuple[float, ...]
    target_tolerance: float
    cruise_turn_rate: float
    heading_gain: float
    swing_height: float
    touchdown_search_speed: float
    touchdown_search_depth: float
    max_step_length: float
    tripod_period: float
    ripple_period: float
    wave_period: float
    still_time: float
    start_ramp: float
    calibration_tilt_deg: float
    calibration_rate_dps: float
    calibration_hold_time: float

    def __post_init__(self) -> None:
        finite("gait speeds", self.speed, self.lateral_speed, self.turn_rate)
        require(abs(self.speed) <= 0.5 and abs(self.lateral_speed) <= 0.5,
                 f"gait speeds must lie within +-0.5 m/s, got {self.speed}, {self.lateral_speed}")
        require(abs(self.turn_rate) <= 2.0, f"gait.turn_rate must lie within +-2 rad/s, got {self.turn_rate}")
        require(len(self.target) in (0, 2), "gait.target must be [] or [x, y]")
        finite("gait.target", *self.target)
        positive("gait.target_tolerance", self.target_tolerance)
        positive("gait touch-down search", self.touchdown_search_speed, self.touchdown_search_depth)
        positive("gait timing", self.cruise_turn_rate, self.heading_gain, self.swing_height,
                         self.max_step_length, self.tripod_period, self.ripple_period, self.wave_period)
        require(math.isfinite(self.start_ramp) and self.start_ramp >= 0, "gait.start_ramp must be >= 0")
        require(math.isfinite(self.still_time) and 0.05 <= self.still_time <= 10,
                 f"gait.still_time must lie in [0.05, 10] s, got {self.still_time}")
        require(math.isfinite(self.calibration_tilt_deg) and 0 <= self.calibration_tilt_deg <= 20,
                 f"gait.calibration_tilt_deg must lie in [0, 20], got {self.calibration_tilt_deg}")
        positive("gait calibration timing", self.calibration_rate_dps, self.calibration_hold_time)

    @property
    def startup_time(self) -> float:
        """s from the start to the first step: standing still, then the calibration poses."""
        from testbed.startup import CalibrationPoses
        return CalibrationPoses.from_gait(self).end

    def period(self, gait: str) -> float:
        return {"tripod": self.tripod_period, "ripple": self.ripple_period, "wave": self.wave_period}.get(gait, 1.0)


@dataclass(frozen=True)
class PostureConfig:
    """The posture controller's gains and limits and the gait's terrain adaptation (docs/control.md)."""
    tilt_kp: float
    tilt_ki: float
    height_kp: float
    height_ki: float
    max_tilt_correction_deg: float
    max_height_correction: float
    walk_plane_time_constant: float
    search_speed: float
    search_depth: float
    touchdown_phase: float

    def __post_init__(self) -> None:
        non_negative("posture gains", self.tilt_kp, self.tilt_ki, self.height_kp, self.height_ki)
        require(0 < self.max_tilt_correction_deg <= 30,
                 f"posture.max_tilt_correction_deg must lie in (0, 30], got {self.max_tilt_correction_deg}")
        require(0 < self.max_height_correction <= 0.08,
                 f"posture.max_height_correction must lie in (0, 0.08] m, got {self.max_height_correction}")
        positive("posture timing", self.walk_plane_time_constant, self.search_speed)
        require(0 < self.search_depth <= 0.1, f"posture.search_depth must lie in (0, 0.1] m, got {self.search_depth}")
        require(0 < self.touchdown_phase < 1, f"posture.touchdown_phase must lie in (0, 1), got {self.touchdown_phase}")


@dataclass(frozen=True)
class Config:
    run: RunConfig
    robot: RobotConfig
    terrain: TerrainConfig
    contact: ContactConfig
    estimators: EstimatorsConfig
    sensors: SensorsConfig
    gait: GaitConfig
    posture: PostureConfig

    def __post_init__(self) -> None:
        self._check_stride()

    def _check_stride(self) -> None:
        """A commanded speed whose stride does not fit the legs' workspace is a config error."""
        from testbed.gait import GAIT_TABLE
        if self.run.gait not in GAIT_TABLE:
            return
        duty = GAIT_TABLE[self.run.gait][0]
        speed = max(math.hypot(self.gait.speed, self.gait.lateral_speed), self.gait.speed)
        stride = speed * duty * self.gait.period(self.run.gait)
        require(stride <= self.gait.max_step_length + 1e-12,
                 f"speed {speed:g} m/s needs a {stride * 100:.1f} cm stride with the {self.run.gait} gait, "
                 f"more than gait.max_step_length {self.gait.max_step_length * 100:.1f} cm")

    def to_dict(self) -> dict[str, Any]:
        return _plain(dataclasses.asdict(self))

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())

    def replace(self, **sections: dict[str, Any]) -> "Config":
        """A copy with some keys of some sections changed: `cfg.replace(run={"terrain": "step"})`."""
        return from_dict(_merge(self.to_dict(), sections))


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def _merge(base: dict[str, Any], override: dict[str, Any], path: str = "") -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        where = f"{path}{key}"
        if key not in base:
            raise ConfigError(f"unknown config key '{where}'")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(f"config key '{where}' must be a table")
            merged[key] = _merge(base[key], value, where + ".")
        else:
            merged[key] = value
    return merged


def _convert(value: Any, hint: Any, where: str) -> Any:
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"config key '{where}' must be a table")
        return _build(hint, value, where + ".")
    origin = typing.get_origin(hint)
    if origin is tuple:
        (item_hint, _ellipsis) = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config key '{where}' must be a list")
        return tuple(_convert(item, item_hint, f"{where}[{i}]") for i, item in enumerate(value))
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key '{where}' must be a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key '{where}' must be an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config key '{where}' must be true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"config key '{where}' must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {hint} at {where}")


def _build(cls: type, data: dict[str, Any], path: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = [field.name for field in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ConfigError(f"unknown config key '{path}{unknown[0]}'")
    missing = [name for name in names if name not in data]
    if missing:
        raise ConfigError(f"missing config key '{path}{missing[0]}'")
    return cls(**{name: _convert(data[name], hints[name], path + name) for name in names})


def default_dict() -> dict[str, Any]:
    text = resources.files("testbed").joinpath("defaults.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def from_dict(data: dict[str, Any]) -> Config:
    return _build(Config, data)


def read_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"cannot read config file {path}: {error}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"invalid TOML in {path}: {error}") from None


def load(path: str | Path | None = None, overrides: dict[str, Any] | None = None,
         base: dict[str, Any] | None = None) -> Config:
    """Defaults (or `base`, e.g. a recorded run's config), then the user's TOML file, then
    command-line overrides; validated."""
    data = default_dict() if base is None else _merge(default_dict(), base)
    if path is not None:
        data = _merge(data, read_toml(path))
    if overrides:
        data = _merge(data, overrides)
    return from_dict(data)
