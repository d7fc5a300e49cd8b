"""One configuration for a run: frozen dataclasses built from `defaults.toml` plus user overrides.

The dataclasses are the schema (names, types, valid ranges); `defaults.toml` holds every default
value. A user's TOML file is merged over the defaults, unknown keys are rejected, and the fully
resolved config is stored with each run (`Config.to_dict`, `Config.to_toml`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import tomli_w

from estimators.config import EstimatorsConfig
from estimators.registry import check_estimator_spec
from sensors.config import SensorsConfig
from testbed.control.config import ClimbLimits, GaitConfig, PostureConfig
from testbed.control.controller import CONTROLLERS
from testbed.control.gait import GAITS
from testbed.model.robot_config import RobotConfig
from testbed.world.config import ContactConfig, TerrainConfig
from testbed.world.contact import CONTACT_MODELS
from testbed.world.terrain import TERRAINS, check_terrain_config
from testbed.model.errors import ConfigError
from testbed.model.validation import finite, non_negative, positive, require


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
        TERRAINS.check_spec(self.terrain)
        CONTACT_MODELS.check_spec(self.contact)
        GAITS.check_spec(self.gait)
        check_estimator_spec(self.estimator)
        CONTROLLERS.check_spec(self.controller)
        require(self.controller != "posture" or self.estimator != "none",
                 "controller 'posture' needs an attitude estimator (--estimator ekf, for example)")
        positive("run.duration", self.duration)
        require(self.duration <= 24 * 3600, f"run.duration {self.duration} s is longer than a day")
        require(0 <= self.seed < 2**63, f"run.seed must be a non-negative integer, got {self.seed}")
        positive("run.time_step", self.time_step)
        require(self.time_step <= 0.01, f"run.time_step {self.time_step} s is too coarse for contact (max 0.01)")
        require(self.duration / self.time_step <= MAX_STEPS,
                f"run.duration / run.time_step is {self.duration / self.time_step:.3g} physics steps, more than "
                f"{MAX_STEPS} (a day at 1 kHz)")
        positive("run.gravity", self.gravity)


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
        self._check_climb()
        check_terrain_config(self)

    def _check_stride(self) -> None:
        """A commanded speed whose stride does not fit the legs' workspace is a config error."""
        if not GAITS.is_known(self.run.gait):
            return      # a plugin gait is checked when it is resolved
        pattern = GAITS.resolve(self.run.gait)
        if not pattern.walks:
            return
        speed = max(math.hypot(self.gait.speed, self.gait.lateral_speed), self.gait.speed)
        stride = speed * pattern.duty * self.gait.period(self.run.gait, pattern.period)
        require(stride <= self.gait.max_step_length + 1e-12,
                 f"speed {speed:g} m/s needs a {stride * 100:.1f} cm stride with the {self.run.gait} gait, "
                 f"more than gait.max_step_length {self.gait.max_step_length * 100:.1f} cm")

    def climb_limits(self) -> ClimbLimits | None:
        """What the built-in pilot's feet can clear and reach down to: with the posture controller
        its raised swings and ground search (`PostureConfig.climb_limits`), without it the swing
        height; None with a plugin controller, whose feet are its own business."""
        swing = self.gait.swing_height
        if self.run.controller == "posture":
            return self.posture.climb_limits(swing)
        return ClimbLimits(swing, swing, swing) if self.run.controller == "none" else None

    def _check_climb(self) -> None:
        """A step or rough ground the posture controller's feet cannot clear or reach down to is
        a config error (courses and height maps: their terrain's `check_config`)."""
        if self.run.controller != "posture" or self.run.terrain not in ("step", "rough"):
            return
        limits = self.climb_limits()
        if self.run.terrain == "step":
            height = self.terrain.step_height
            require(height <= limits.up + 1e-12, f"terrain.step_height {height:g} m is higher than the feet can clear: "
                                                 f"at most {limits.up:g} m (posture.max_swing_height less posture.step_clearance)")
            require(-height <= limits.down + 1e-12, f"terrain.step_height {height:g} m is deeper than the feet reach "
                                                    f"down: at most {limits.down:g} m (posture.search_depth)")
            return
        amplitude = self.terrain.rough_amplitude
        require(amplitude <= limits.rough_amplitude + 1e-12,
                 f"terrain.rough_amplitude {amplitude:g} m is more than the feet can clear or reach down: at most "
                 f"{limits.rough_amplitude:g} m (half posture.max_swing_height, posture.search_depth)")

    @property
    def startup_time(self) -> float:
        """s from the start to the first step (`GaitConfig.startup_time` for this run's duration)."""
        return self.gait.startup_time(self.run.duration)

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
    if origin is types.UnionType:
        return _convert_either(value, typing.get_args(hint), where)
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


def _convert_either(value: Any, hints: tuple[Any, ...], where: str) -> Any:
    """A value of the first of `hints` (e.g. float | str) that takes it."""
    for hint in hints:
        try:
            return _convert(value, hint, where)
        except ConfigError:
            continue
    names = " or ".join({float: "a number", int: "an integer", str: "a string", bool: "true or false"}.get(hint, str(hint))
                        for hint in hints)
    raise ConfigError(f"config key '{where}' must be {names}, got {value!r}")


def _build(cls: type, data: dict[str, Any], path: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = [field.name for field in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ConfigError(f"unknown config key '{path}{unknown[0]}'")
    optional = {field.name for field in dataclasses.fields(cls)
                if field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING}
    missing = [name for name in names if name not in data and name not in optional]
    if missing:
        raise ConfigError(f"missing config key '{path}{missing[0]}'")
    return cls(**{name: _convert(data[name], hints[name], path + name) for name in names if name in data})


def default_dict() -> dict[str, Any]:
    text = resources.files("testbed").joinpath("defaults.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def from_dict(data: dict[str, Any]) -> Config:
    return _build(Config, data)


MAX_CONFIG_BYTES = 2**20    # a config file is a few kB
MAX_STEPS = 86_400_000      # physics steps of one run: a day at 1 kHz


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML config file: a regular file (not a FIFO or a device, which could block or never end)
    of at most MAX_CONFIG_BYTES."""
    path = Path(path)
    try:
        if path.exists() and not path.is_file():
            raise ConfigError(f"config file {path} is not a regular file")
        with open(path, "rb") as stream:
            data = stream.read(MAX_CONFIG_BYTES + 1)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(f"config file {path} is larger than {MAX_CONFIG_BYTES // 1024} kB")
        text = data.decode("utf-8")
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
