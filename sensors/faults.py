"""Fault injection: the fault-spec grammar and the injector that applies faults to one sample stream.

    SPEC   = TARGET "." KIND "@" START ["+" DURATION] [":" VALUE]
    TARGET = imu[.accel|.gyro[.x|.y|.z]] | accel_array[.INDEX[.x|.y|.z]]
           | encoder[.legN[.coxa|.femur|.tibia]] | foot[.legN]          (N = 1..6)
    KIND   = dropout | stuck | spike | bias_step
    START, DURATION = a number with unit s or ms;  VALUE = a number in the channel's SI unit

Examples: imu.accel.spike@5s, encoder.dropout@3s+1s, imu.gyro.z.bias_step@4s:0.02,
foot.leg3.stuck@2s+1s. docs/sensors.md gives the meaning of each kind.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from testbed.model.errors import ConfigError

KINDS = ("dropout", "stuck", "spike", "bias_step")
AXES = ("x", "y", "z")
JOINTS = ("coxa", "femur", "tibia")
LEGS = 6
# Channels of one sample vector: the IMU's is accel x y z then gyro x y z, an encoder sample holds
# 18 joints leg-major, a foot sample 6 forces, an accel_array member 3 axes.
IMU_PARTS = {"accel": 0, "gyro": 3}
TIME_EPS = 1e-9     # s, sample times k/rate within this of a boundary count as on it
GRAMMAR = "SENSOR[.CHANNEL].KIND@START[+DURATION][:VALUE], e.g. imu.accel.spike@5s or encoder.leg2.dropout@3s+1s"
_TIME = re.compile(r"(\d+(?:\.\d*)?|\.\d+)(ms|s)")


@dataclass(frozen=True)
class Fault:
    spec: str
    sensor: str                         # imu | accel_array | encoder | foot
    member: int | None                  # accel_array member (AccelSample.index); None: every member
    channels: tuple[int, ...] | None    # indices into one sample vector (see above); None: all
    kind: str
    start: float                        # s
    end: float                          # s, math.inf when no duration was given
    value: float | None                 # SI unit of the channel

    def active(self, t: float) -> bool:
        return self.start - TIME_EPS <= t < self.end - TIME_EPS


class _SpecError(Exception):
    pass


def parse_fault(spec: str) -> Fault:
    """Parse one fault spec; raises ConfigError naming the spec and what is wrong with it."""
    try:
        return _parse(spec.strip())
    except _SpecError as error:
        raise ConfigError(f"bad fault '{spec}': {error} (grammar: {GRAMMAR})") from None


def _parse(spec: str) -> Fault:
    head, at, timing = spec.partition("@")
    if not at:
        raise _SpecError("no '@START' time")
    *path, kind = head.split(".")
    if kind not in KINDS:
        raise _SpecError(f"unknown kind '{kind}' (choose from {', '.join(KINDS)})")
    sensor, member, channels = _parse_target(path)
    timing, colon, value_text = timing.partition(":")
    start_text, plus, duration_text = timing.partition("+")
    start = _parse_time(start_text)
    duration = _parse_time(duration_text) if plus else None
    value = _parse_value(value_text) if colon else None
    _check_kind_arguments(kind, duration, value)
    if duration is not None and duration <= 0:
        raise _SpecError("the duration must be positive")
    end = math.inf if duration is None else start + duration
    return Fault(spec, sensor, member, channels, kind, start, end, value)


def _parse_target(path: list[str]) -> tuple[str, int | None, tuple[int, ...] | None]:
    if not path:
        raise _SpecError("no sensor (imu, accel_array, encoder, foot)")
    sensor, rest = path[0], path[1:]
    parsers = {"imu": _imu_channels, "accel_array": _array_channels, "encoder": _encoder_channels,
               "foot": _foot_channels}
    if sensor not in parsers:
        raise _SpecError(f"unknown sensor '{sensor}' (choose from {', '.join(parsers)})")
    member, channels = parsers[sensor](rest)
    return sensor, member, channels


def _imu_channels(rest: list[str]) -> tuple[None, tuple[int, ...] | None]:
    if not rest:
        return None, None
    part, *axis = rest
    if part not in IMU_PARTS or len(axis) > 1:
        raise _SpecError("an imu channel is accel or gyro, optionally followed by .x, .y or .z")
    offset = IMU_PARTS[part]
    return None, (offset + _axis(axis[0]),) if axis else (offset, offset + 1, offset + 2)


def _array_channels(rest: list[str]) -> tuple[int | None, tuple[int, ...] | None]:
    if not rest:
        return None, None
    index, *axis = rest
    if not (index.isascii() and index.isdigit()) or len(axis) > 1:
        raise _SpecError("an accel_array channel is a member index (0, 1, ...), optionally followed by .x, .y or .z")
    return int(index), (_axis(axis[0]),) if axis else None


def _encoder_channels(rest: list[str]) -> tuple[None, tuple[int, ...] | None]:
    if not rest:
        return None, None
    leg, *joint = rest
    first = 3 * _leg(leg)
    if len(joint) > 1 or (joint and joint[0] not in JOINTS):
        raise _SpecError(f"an encoder channel is legN, optionally followed by .{', .'.join(JOINTS)}")
    return None, (first + JOINTS.index(joint[0]),) if joint else (first, first + 1, first + 2)


def _foot_channels(rest: list[str]) -> tuple[None, tuple[int, ...] | None]:
    if not rest:
        return None, None
    if len(rest) > 1:
        raise _SpecError("a foot channel is legN")
    return None, (_leg(rest[0]),)


def _axis(text: str) -> int:
    if text not in AXES:
        raise _SpecError(f"unknown axis '{text}' (choose from x, y, z)")
    return AXES.index(text)


def _leg(text: str) -> int:
    number = text.removeprefix("leg")
    if not (text.startswith("leg") and number.isascii() and number.isdigit() and 1 <= int(number) <= LEGS):
        raise _SpecError(f"unknown leg '{text}' (leg1 ... leg{LEGS})")
    return int(number) - 1


def _parse_time(text: str) -> float:
    match = _TIME.fullmatch(text)
    if not match:
        raise _SpecError(f"time '{text}' must be a non-negative number with unit s or ms, like 5s or 250ms")
    number, unit = match.groups()
    return float(number) / (1000.0 if unit == "ms" else 1.0)


def _parse_value(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _SpecError(f"value '{text}' is not a number") from None
    if not math.isfinite(value):
        raise _SpecError(f"value '{text}' must be finite")
    return value


def _check_kind_arguments(kind: str, duration: float | None, value: float | None) -> None:
    if kind == "spike" and duration is not None:
        raise _SpecError("a spike hits one sample and takes no +DURATION")
    if kind == "bias_step" and value is None:
        raise _SpecError("a bias_step needs its size, like :0.02")
    if kind == "dropout" and value is not None:
        raise _SpecError("a dropout takes no :VALUE")


class FaultInjector:
    """Applies the faults of one stream to its sample vectors, which arrive in time order.

    `disturb` adds spikes and bias steps to the analog value (before saturation and quantization);
    `hold` replaces stuck channels and blanks dropped ones (NaN) in the digital output.
    """

    def __init__(self, faults: Sequence[Fault], sensor: str, width: int, full_scale: np.ndarray,
                 members: int = 1) -> None:
        self._targets = [(fault, _stream_channels(fault, width, members)) for fault in faults if fault.sensor == sensor]
        self._full_scale = full_scale
        self._fired: set[int] = set()
        self._held: dict[int, np.ndarray] = {}
        self._last: np.ndarray | None = None

    def __bool__(self) -> bool:
        return bool(self._targets)

    def disturb(self, t: float, raw: np.ndarray) -> np.ndarray:
        for number, (fault, channels) in enumerate(self._targets):
            if fault.kind == "bias_step" and fault.active(t):
                raw[channels] += fault.value
            elif fault.kind == "spike" and fault.active(t) and number not in self._fired:
                self._fired.add(number)
                raw[channels] += self._full_scale[channels] if fault.value is None else fault.value
        return raw

    def hold(self, t: float, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output with faults applied, and the mask of its dropped channels."""
        dropped = np.zeros(out.shape, dtype=bool)
        for number, (fault, channels) in enumerate(self._targets):
            if not fault.active(t):
                continue
            if fault.kind == "stuck":
                out[channels] = self._stuck_value(number, fault, channels, out)
            elif fault.kind == "dropout":
                dropped[channels] = True
        out[dropped] = np.nan
        if not dropped.all():
            self._last = out.copy()
        return out, dropped

    def _stuck_value(self, number: int, fault: Fault, channels: np.ndarray, out: np.ndarray) -> np.ndarray:
        if number not in self._held:
            if fault.value is not None:
                self._held[number] = np.full(len(channels), fault.value)
            else:
                source = out if self._last is None else self._last
                self._held[number] = source[channels].copy()
        return self._held[number]


def _stream_channels(fault: Fault, width: int, members: int) -> np.ndarray:
    """Indices of the fault's channels in a stream of `members` stacked vectors of `width` channels."""
    chosen_members = range(members) if fault.member is None else (fault.member,)
    channels = range(width) if fault.channels is None else fault.channels
    return np.array([member * width + channel for member in chosen_members for channel in channels], dtype=int)
