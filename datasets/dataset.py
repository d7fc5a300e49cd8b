"""A recorded run for notebooks: its config, its metrics, its topics, and any topic as a pandas
table (`Dataset.table`).

A table has a `t` column (s: the simulation time each message carries) and one column per value
of every field, named after the field:

| field holds | columns | example |
|---|---|---|
| one value | the field's name | `roll`, `index`, `stability_margin` |
| a 3-vector | `_x`, `_y`, `_z` | `accel_x`, `gyro_z`, `body_position_y` |
| a quaternion (x, y, z, w) | `_x`, `_y`, `_z`, `_w` | `quaternion_w`, `orientation_x` |
| a 3 x 3 matrix | `_RC`, row R and column C from 0, row-major | `attitude_cov_01`, `body_rotation_22` |
| a value per joint (18, leg-major) | `_legL_coxa`, `_legL_femur`, `_legL_tibia` (joints 1, 2, 3 of leg L) | `positions_leg2_femur` |
| a 3-vector per foot (6, 3) | `_legL_x`, `_legL_y`, `_legL_z` | `foot_targets_leg1_z` |
| a value per leg (6) | `_legL` | `contact_leg4`, `phase_leg6` |
| the commanded twist | `_vx`, `_vy`, `_wz` | `body_twist_vx` |
| polygon vertices (x, y each) | `_vK_x`, `_vK_y`, K from 1 | `polygon_v3_y` |
| anything else | `_I`, I from 0 | |

Legs are numbered 1 to 6 as in the config. An optional field that a message leaves out, and the
values of a field that a message holds fewer of than others (a polygon with fewer vertices, an
estimator that gives no covariance), are NaN.

Reading is columnar: the file's chunk index names the chunks that hold the topic and each chunk's
message index where in it the topic's messages lie, so the other topics' messages are never
parsed; each message is decoded with its protobuf class (datasets/schemas.py), and each field's
values over all the messages become columns at once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from datasets import heightmap_store, schemas
from datasets.message_columns import Ragged, message_columns
from datasets.reader import RECORD_HEADER, chunk_records, message_index_pairs, message_payloads
from testbed.model.errors import ConfigError, UserError
from testbed.runtime import config as config_module
from testbed.runtime.config import Config

LEGS = range(1, 7)
XYZ = ("x", "y", "z")
_VECTOR = tuple(f"_{axis}" for axis in XYZ)
_QUATERNION = ("_x", "_y", "_z", "_w")
_MATRIX = tuple(f"_{row}{column}" for row in range(3) for column in range(3))
_PER_JOINT = tuple(f"_leg{leg}_{link}" for leg in LEGS for link in ("coxa", "femur", "tibia"))
_PER_FOOT = tuple(f"_leg{leg}_{axis}" for leg in LEGS for axis in XYZ)
_PER_LEG = tuple(f"_leg{leg}" for leg in LEGS)
_POLYGON = tuple(f"_v{vertex}_{axis}" for vertex in LEGS for axis in ("x", "y"))

# Column suffixes of each repeated field of the dataset's messages (datasets/schemas.py).
SUFFIXES: dict[str, tuple[str, ...]] = {
    **dict.fromkeys(("accel", "gyro", "gyro_bias", "body_position", "body_linear_velocity", "body_angular_velocity",
                     "body_linear_acceleration", "body_angular_acceleration", "com_position", "position",
                     "translation"), _VECTOR),
    **dict.fromkeys(("quaternion", "orientation", "rotation"), _QUATERNION),
    **dict.fromkeys(("body_rotation", "attitude_cov", "gyro_bias_cov", "terrain_cov"), _MATRIX),
    **dict.fromkeys(("positions", "joint_positions", "joint_velocities", "joint_targets"), _PER_JOINT),
    **dict.fromkeys(("foot_positions", "foot_forces", "foot_targets", "points", "normals", "forces"), _PER_FOOT),
    **dict.fromkeys(("normal_forces", "contact", "foot_normal_forces", "foot_contact", "in_contact", "phase",
                     "swinging"), _PER_LEG),
    "body_twist": ("_vx", "_vy", "_wz"),
    "com_projection": ("_x", "_y"),
    "polygon": _POLYGON,
}

# The foxglove messages' values that make a table: (column prefix, path of nested fields).
FOXGLOVE_FIELDS: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "foxglove.PoseInFrame": (("position", ("pose", "position")), ("orientation", ("pose", "orientation"))),
    "foxglove.FrameTransform": (("translation", ("translation",)), ("rotation", ("rotation",))),
}
NS_PER_S = 1_000_000_000
TRANSFORMS = "foxglove.FrameTransforms"     # /tf: a table of every frame's transform


@dataclass(frozen=True)
class _Channel:
    id: int
    topic: str
    message_class: type


class Dataset:
    """A run's MCAP file (`testbed.load`): `.config`, `.metrics`, `.topics`, `.table(topic)`."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise UserError(f"{self.path}: no such file")
        with self.path.open("rb") as stream:
            try:
                reader = make_reader(stream)
                self._metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
                self._attachments = {record.name: record.data for record in reader.iter_attachments()
                                     if record.name == heightmap_store.ATTACHMENT}
                summary = reader.get_summary()
            except (McapError, ValueError, EOFError) as error:
                raise UserError(f"{self.path} is not a readable MCAP file ({error})") from None
        if summary is None:
            raise UserError(f"{self.path} has no summary (a run cut short): read it with `testbed info`")
        self._summary = summary
        classes = {topic.name: topic.message_class for topic in schemas.TOPICS}
        self._channels = {channel.topic: _Channel(channel.id, channel.topic, classes[channel.topic])
                          for channel in summary.channels.values() if channel.topic in classes}

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r})"

    @cached_property
    def config(self) -> Config:
        """The run's fully resolved config."""
        try:
            data = json.loads(self._metadata["config"]["json"])
        except (KeyError, json.JSONDecodeError):
            raise UserError(f"{self.path} holds no testbed run config: not a testbed dataset") from None
        try:
            return config_module.from_dict(heightmap_store.restored_config(data, self._attachments, self.path))
        except ConfigError as error:
            raise UserError(f"{self.path}: its recorded config does not fit this testbed version ({error})") from None

    @property
    def metrics(self) -> dict | None:
        """The metrics the run stored when it finished (None for a run that did not finish)."""
        text = self._metadata.get("metrics", {}).get("json")
        return None if text is None else json.loads(text)

    @property
    def run_info(self) -> dict[str, str]:
        """The run's description: terrain, estimator, gait, seed, time step, ... as strings."""
        return dict(self._metadata.get("run", {}))

    @property
    def topics(self) -> list[str]:
        """The topics that hold messages, in the order of docs/dataset.md."""
        statistics = self._summary.statistics
        order = [topic.name for topic in schemas.TOPICS if topic.name in self._channels]
        if statistics is None:
            return order
        return [topic for topic in order if statistics.channel_message_counts.get(self._channels[topic].id, 0)]

    def table(self, topic: str) -> pandas.DataFrame:
        """The topic's messages, one row each in time order: `t` (s) and every field flattened
        (the module's docstring names the columns)."""
        channel = self._channels.get(topic)
        if channel is None:
            raise UserError(f"{self.path} has no topic {topic} (topics: {', '.join(self.topics)})")
        if topic == schemas.TERRAIN.name:
            raise UserError(f"{topic} holds the terrain's boxes, not a time series")
        payloads = self._payloads(channel)
        columns = _columns(channel.message_class, payloads)
        order = np.argsort(columns["t"], kind="stable")
        if np.any(order != np.arange(len(order))):
            columns = {name: values[order] for name, values in columns.items()}
        return pandas.DataFrame(columns, copy=False)

    def _payloads(self, channel: _Channel) -> list[bytes]:
        """The serialised messages of one channel, chunk by chunk in file order."""
        payloads: list[bytes] = []
        with self.path.open("rb") as stream:
            for chunk_index in self._summary.chunk_indexes:
                index_offset = chunk_index.message_index_offsets.get(channel.id)
                if index_offset is None and chunk_index.message_index_offsets:
                    continue        # indexed, without this channel
                if index_offset is None:
                    stream.seek(chunk_index.chunk_start_offset + RECORD_HEADER.size)
                    payloads += [record.data for record in breakup_chunk(Chunk.read(ReadDataStream(stream)))
                                 if isinstance(record, Message) and record.channel_id == channel.id]
                    continue
                offsets = message_index_pairs(stream, index_offset)[:, 1].astype(np.int64)
                payloads += message_payloads(chunk_records(stream, chunk_index), offsets)
        return payloads


def _columns(message_class: type, payloads: list[bytes]) -> dict[str, np.ndarray]:
    name = message_class.DESCRIPTOR.full_name
    if name == TRANSFORMS:
        return _transforms_columns(message_class, payloads)
    if name in FOXGLOVE_FIELDS:
        return _foxglove_columns(message_class, FOXGLOVE_FIELDS[name], payloads)
    return _hexapod_columns(message_class, payloads)


def _hexapod_columns(message_class: type, payloads: list[bytes]) -> dict[str, np.ndarray]:
    columns: dict[str, np.ndarray] = {}
    for name, column in message_columns(message_class, payloads).items():
        if isinstance(column, Ragged):
            columns.update(_repeated_columns(name, column))
        else:
            columns[name] = column
    return columns


def _repeated_columns(name: str, column: Ragged) -> dict[str, np.ndarray]:
    """The table columns of a repeated field."""
    suffixes = SUFFIXES.get(name)
    width = int(column.lengths.max(initial=0))
    if suffixes is None or width > len(suffixes):
        suffixes = tuple(f"_{i}" for i in range(width))
    table = column.table(len(suffixes))
    return {name + suffix: table[:, i] for i, suffix in enumerate(suffixes)}


def _foxglove_columns(message_class: type, fields: tuple[tuple[str, tuple[str, ...]], ...],
                      payloads: list[bytes]) -> dict[str, np.ndarray]:
    """`t` from the timestamp, then the components of each nested message in `fields`."""
    message = message_class()
    names = ["t"] + [f"{prefix}_{component.name}" for prefix, path in fields
                     for component in _nested(message, path).DESCRIPTOR.fields]
    rows = []
    for data in payloads:
        message.ParseFromString(data)
        row = [message.timestamp.seconds + message.timestamp.nanos / NS_PER_S]
        for _prefix, path in fields:
            nested = _nested(message, path)
            row += [getattr(nested, component.name) for component in nested.DESCRIPTOR.fields]
        rows.append(row)
    table = np.asarray(rows, dtype=float).reshape(len(rows), len(names))
    return {name: table[:, i] for i, name in enumerate(names)}


def _transforms_columns(message_class: type, payloads: list[bytes]) -> dict[str, np.ndarray]:
    """`t`, then each transform's translation and rotation, prefixed by its child frame:
    `body_translation_x`, `leg1_femur_rotation_w`, ... (the frames of the first message)."""
    messages = list(map(message_class.FromString, payloads))
    frames = [transform.child_frame_id for transform in messages[0].transforms] if messages else []
    names = ["t"] + [f"{frame}_{part}_{axis}" for frame in frames for part, axes in (("translation", XYZ),
                                                                                       ("rotation", XYZ + ("w",)))
                     for axis in axes]
    table = np.full((len(messages), len(names)), np.nan)
    for row, message in enumerate(messages):
        stamp = message.transforms[0].timestamp if message.transforms else None
        table[row, 0] = np.nan if stamp is None else stamp.seconds + stamp.nanos / NS_PER_S
        values = [value for transform in message.transforms[:len(frames)]
                  for value in (transform.translation.x, transform.translation.y, transform.translation.z,
                                transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w)]
        table[row, 1:1 + len(values)] = values
    return {name: table[:, i] for i, name in enumerate(names)}


def _nested(message, path: tuple[str, ...]):
    for name in path:
        message = getattr(message, name)
    return message


def load(path: str | Path) -> Dataset:
    """The recorded run at `path`."""
    return Dataset(path)
