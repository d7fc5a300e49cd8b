"""Sensor configuration: frozen dataclasses (names, types, valid ranges) for the `[sensors]` tables
of testbed/defaults.toml, which hold every default value. Units are SI unless a key ends in _deg.

The estimator side learns the sensor geometry (IMU pose, accelerometer positions), rates and noise
levels from this config, never from ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from sensors.faults import Fault, parse_fault
from testbed.model.validation import non_negative, require

ACCEL_ARRAY_LAYOUTS = ("imu_only", "quad", "custom")
# The "quad" layout: four accelerometers near the corners of the top plate of the 0.20 x 0.15 x
# 0.04 m body, counter-clockwise from the front left like the legs (m, body frame).
QUAD_POSITIONS = ((0.08, 0.06, 0.02), (-0.08, 0.06, 0.02), (-0.08, -0.06, 0.02), (0.08, -0.06, 0.02))
MAX_RATE = 10_000.0    # Hz




def _read_only(array: np.ndarray) -> np.ndarray:
    """A config is immutable; so are the arrays it derives."""
    array.setflags(write=False)
    return array


def _check_rate(name: str, rate: float) -> None:
    require(math.isfinite(rate) and 0 < rate <= MAX_RATE, f"{name} must lie in (0, {MAX_RATE:g}] Hz, got {rate}")




def _check_vector(name: str, values: tuple[float, ...], length: int) -> None:
    require(len(values) == length, f"{name} needs {length} numbers, got {len(values)}")
    require(all(math.isfinite(v) for v in values), f"{name} must be finite, got {list(values)}")


@dataclass(frozen=True)
class InertialAxesConfig:
    """Three axes of one accelerometer or gyro; values in m/s^2 (accelerometer) or rad/s (gyro)."""
    noise_density: float        # unit/sqrt(Hz): white noise, Allan deviation at tau = 1 s
    bias_instability: float     # unit: flicker floor of the Allan deviation / 0.664
    rate_random_walk: float     # unit/sqrt(s): Allan deviation K sqrt(tau / 3) of the bias random walk
    turn_on_bias: float         # unit, 1 sigma per axis, drawn once per run
    scale_factor: float         # 1 sigma relative scale-factor error per axis
    misalignment: float         # rad, 1 sigma of each cross-axis coupling term
    range: float                # unit, full scale +-range
    bits: int                   # ADC resolution over the full scale

    def check(self, where: str) -> None:
        """Validate, naming the table (`where`) in the message: the same class serves accel and gyro."""
        for name in ("noise_density", "bias_instability", "rate_random_walk", "turn_on_bias"):
            non_negative(f"{where}.{name}", getattr(self, name))
        require(math.isfinite(self.scale_factor) and 0 <= self.scale_factor <= 0.1,
                 f"{where}.scale_factor must lie in [0, 0.1], got {self.scale_factor}")
        require(math.isfinite(self.misalignment) and 0 <= self.misalignment <= 0.1,
                 f"{where}.misalignment must lie in [0, 0.1] rad, got {self.misalignment}")
        require(math.isfinite(self.range) and self.range > 0,
                 f"{where}.range must be a positive finite number, got {self.range}")
        require(4 <= self.bits <= 32, f"{where}.bits must lie in [4, 32], got {self.bits}")

    @property
    def lsb(self) -> float:
        return 2 * self.range / 2**self.bits


@dataclass(frozen=True)
class ImuConfig:
    rate: float                 # Hz, accelerometer and gyro sampled together
    position: tuple[float, ...]     # m, body frame: the accelerometer's proof-mass point
    rpy_deg: tuple[float, ...]      # sensor frame relative to the body frame: roll, pitch, yaw
    accel: InertialAxesConfig
    gyro: InertialAxesConfig

    def __post_init__(self) -> None:
        _check_rate("sensors.imu.rate", self.rate)
        _check_vector("sensors.imu.position", self.position, 3)
        require(all(abs(v) <= 1.0 for v in self.position), "sensors.imu.position must lie within 1 m of the body origin")
        _check_vector("sensors.imu.rpy_deg", self.rpy_deg, 3)
        self.accel.check("sensors.imu.accel")
        self.gyro.check("sensors.imu.gyro")

    @cached_property
    def body_from_sensor(self) -> np.ndarray:
        """(3, 3) rotation R_bs = Rz(yaw) Ry(pitch) Rx(roll): sensor-frame vectors to the body frame."""
        roll, pitch, yaw = self.rpy_deg
        return _read_only(Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix())


@dataclass(frozen=True)
class AccelArrayConfig:
    """Extra 3-axis accelerometers (same model as the IMU's) with axes parallel to the body axes."""
    layout: str                             # imu_only | quad | custom
    positions: tuple[tuple[float, ...], ...]    # m, body frame, one [x, y, z] per accelerometer (custom only)
    rate: float                             # Hz

    def __post_init__(self) -> None:
        require(self.layout in ACCEL_ARRAY_LAYOUTS,
                 f"unknown sensors.accel_array.layout '{self.layout}' (choose from {', '.join(ACCEL_ARRAY_LAYOUTS)})")
        if self.layout == "custom":
            require(1 <= len(self.positions) <= 64, "sensors.accel_array.positions needs 1 to 64 [x, y, z] points")
        else:
            require(not self.positions, f"sensors.accel_array.positions is only for layout 'custom', not '{self.layout}'")
        for i, point in enumerate(self.positions):
            _check_vector(f"sensors.accel_array.positions[{i}]", point, 3)
        _check_rate("sensors.accel_array.rate", self.rate)

    @cached_property
    def member_positions(self) -> np.ndarray:
        """(N, 3) m, body frame; row i is the accelerometer of AccelSample.index i."""
        points = {"imu_only": (), "quad": QUAD_POSITIONS, "custom": self.positions}[self.layout]
        return _read_only(np.array(points, dtype=float).reshape(-1, 3))


@dataclass(frozen=True)
class EncoderConfig:
    bits: int                   # absolute encoder resolution over one turn
    noise: float                # rad, 1 sigma before quantization
    rate: float                 # Hz

    def __post_init__(self) -> None:
        require(4 <= self.bits <= 24, f"sensors.encoder.bits must lie in [4, 24], got {self.bits}")
        non_negative("sensors.encoder.noise", self.noise)
        _check_rate("sensors.encoder.rate", self.rate)

    @property
    def lsb(self) -> float:
        return 2 * math.pi / 2**self.bits


@dataclass(frozen=True)
class FootConfig:
    rate: float                 # Hz
    noise: float                # N, 1 sigma
    full_scale: float           # N, readings saturate at +-full_scale
    contact_on: float           # N, contact flag rises above this force
    contact_off: float          # N, and falls below this one (hysteresis)

    def __post_init__(self) -> None:
        _check_rate("sensors.foot.rate", self.rate)
        non_negative("sensors.foot.noise", self.noise)
        require(math.isfinite(self.full_scale) and self.full_scale > 0,
                 f"sensors.foot.full_scale must be a positive finite number, got {self.full_scale}")
        require(math.isfinite(self.contact_on) and math.isfinite(self.contact_off)
                 and 0 <= self.contact_off < self.contact_on < self.full_scale,
                 "sensors.foot thresholds must satisfy 0 <= contact_off < contact_on < full_scale, "
                 f"got contact_off={self.contact_off}, contact_on={self.contact_on}")


@dataclass(frozen=True)
class SensorsConfig:
    faults: tuple[str, ...]     # fault specs, docs/sensors.md; the CLI's --fault adds to these
    imu: ImuConfig
    accel_array: AccelArrayConfig
    encoder: EncoderConfig
    foot: FootConfig

    def __post_init__(self) -> None:
        members = len(self.accel_array.member_positions)
        for fault in self.parsed_faults:
            require(fault.member is None or fault.member < members,
                     f"fault '{fault.spec}': accel_array has {members} member(s) with layout '{self.accel_array.layout}'")

    @cached_property
    def parsed_faults(self) -> tuple[Fault, ...]:
        return tuple(parse_fault(spec) for spec in self.faults)
