"""Sensor presets: named grades of IMU as config overrides (`testbed/presets/<name>.toml`).

A preset is a partial config in the format of `testbed/defaults.toml` (usually `[sensors.imu.*]`
plus the estimators' matching noise beliefs) merged over a config:

    cfg = config.load(path, preset_overrides("consumer"))
    cfg = cfg.replace(**preset_overrides("tactical"))

`default` changes nothing. The data-sheet sources are cited in each file's comments.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from typing import Any

from testbed.model.errors import ConfigError

PRESET_FOLDER = "presets"
DEFAULT_PRESET = "default"


def _folder():
    return resources.files("testbed").joinpath(PRESET_FOLDER)


def preset_names() -> tuple[str, ...]:
    """Every preset shipped with the package, `default` first, then alphabetically."""
    names = sorted(entry.name.removesuffix(".toml") for entry in _folder().iterdir()
                   if entry.name.endswith(".toml"))
    return tuple(sorted(names, key=lambda name: name != DEFAULT_PRESET))


def preset_overrides(name: str) -> dict[str, Any]:
    """The config override of preset `name` (a fresh dict: the caller may change it)."""
    if name not in preset_names():
        raise ConfigError(f"unknown sensor preset '{name}' (choose from {', '.join(preset_names())})")
    text = _folder().joinpath(f"{name}.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)
