"""Timestamped sensor samples: what sensors emit and what estimators consume.

Every sample carries its own timestamp (s, simulation time); streams at different rates are
delivered in time order as they occur.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImuSample:
    t: float
    accel: np.ndarray        # (3,) m/s^2, specific force in the IMU frame
    gyro: np.ndarray         # (3,) rad/s, angular rate in the IMU frame


@dataclass(frozen=True)
class AccelSample:
    """One member of the accelerometer array (the IMU's accelerometer is index 0 of no array)."""
    t: float
    index: int
    accel: np.ndarray        # (3,) m/s^2, specific force in that accelerometer's frame


@dataclass(frozen=True)
class EncoderSample:
    t: float
    positions: np.ndarray    # (18,) rad, leg-major like Truth.joint_positions


@dataclass(frozen=True)
class FootSample:
    t: float
    normal_forces: np.ndarray    # (6,) N
    contact: np.ndarray          # (6,) bool, after threshold and hysteresis


Sample = ImuSample | AccelSample | EncoderSample | FootSample
