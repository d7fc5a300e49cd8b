"""Checks shared by the config dataclasses of every package: one clear ConfigError message each."""

from __future__ import annotations

import math

from testbed.model.errors import ConfigError


def require(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def finite(name: str, *values: float) -> None:
    for value in values:
        require(math.isfinite(value), f"{name} must be finite, got {value}")


def positive(name: str, *values: float) -> None:
    for value in values:
        require(math.isfinite(value) and value > 0, f"{name} must be a positive finite number, got {value}")


def non_negative(name: str, *values: float) -> None:
    for value in values:
        require(math.isfinite(value) and value >= 0, f"{name} must be a finite number >= 0, got {value}")
