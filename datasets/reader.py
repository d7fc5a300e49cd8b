"""Read a recorded run back: samples, estimates, truth, commands, config, metrics, URDF.

The file is read front to back, record by record, so the same code reads a complete file and a
truncated one (a run killed outright, a copy cut short): reading stops at the first record that
is incomplete or fails its CRC, keeps everything before it and notes why (`Recording.truncated`).
Bad input raises `testbed.model.errors.UserError` with a one-line message.
"""

from __future__ import annotations

import importlib
import json
import struct
import zlib
from xml.etree import ElementTree
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass, field, fields
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, ChunkIndex, Footer, Message, Metadata, Schema
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.stream_reader import CRCValidationError, StreamReader
import zstandard

from datasets import codec, heightmap_store, schemas
from datasets.message_columns import Ragged, message_columns
from datasets.scoring import ScoringTruth
from estimators.base import Estimate
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.world.contact import FootContacts
from testbed.model.errors import ConfigError, UserError
from testbed.control.command import Command
from testbed.model.truth import Truth

MCAP_MAGIC = b"\x89MCAP0\r\n"
SCORING_TOPICS = frozenset({schemas.TRUTH_POSE.name, schemas.TRUTH_FEET.name})
REPLAY_TOPICS = frozenset({schemas.SENSOR_PREFIX}) | SCORING_TOPICS
ALL_TOPICS = None
# Record layouts of the MCAP specification (little-endian): every record starts with its opcode
# and its length; a Message Index holds (log time, offset in the chunk) pairs, a Message its
# channel id, sequence, log and publish time, then the data.
MAX_CHUNK_BYTES = 64 * 2**20     # a chunk's records, decompressed (the testbed writes at most 8 MiB)
MAX_RECORD_BYTES = 256 * 2**20   # one record of the file (a chunk, compressed; an attachment)
MAX_JSON_DEPTH = 64              # nesting of the recorded JSON (config, metrics)
RECORD_HEADER = struct.Struct("<BQ")
MESSAGE_INDEX_HEADER = struct.Struct("<BQHI")       # record header, channel id, length of the pairs
MESSAGE_HEADER = struct.Struct("<BQHIQQ")


@dataclass
class TopicStats:
    schema: str = ""
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    def add(self, log_ns: int) -> None:
        self.add_many(1, log_ns, log_ns)

    def add_many(self, count: int, first_ns: int, last_ns: int) -> None:
        self.count += count
        self.first_ns = first_ns if self.first_ns is None else min(self.first_ns, first_ns)
        self.last_ns = last_ns if self.last_ns is None else max(self.last_ns, last_ns)

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.last_ns == self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) / codec.NS_PER_S)


@dataclass
class Recording:
    path: Path
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    topics: dict[str, TopicStats] = field(default_factory=dict)          # every channel of the file
    messages: dict[str, list[tuple[int, int, bytes]]] = field(default_factory=dict)  # kept topics: (log ns, sequence, data)
    channel_metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: str | None = None      # why reading stopped before the end of a complete file

    # --- run description ----------------------------------------------------------------------

    def config_dict(self) -> dict[str, Any]:
        """The recorded config; a recorded height map is restored to a file it names."""
        if "config" not in self.metadata:
            raise UserError(f"{self.path} holds no testbed run config: not a testbed dataset"
                            + (f" (it is truncated: {self.truncated})" if self.truncated else ""))
        config = _recorded_json(self.metadata["config"].get("json"), f"{self.path}: its recorded config")
        if not isinstance(config, dict):
            raise UserError(f"{self.path}: its recorded config is damaged (not a JSON table)")
        return heightmap_store.restored_config(config, self.attachments, self.path)

    def config(self) -> Config:
        """The recorded config; keys added to the testbed since the recording take their defaults."""
        try:
            return config_module.load(base=self.config_dict())
        except ConfigError as error:
            raise UserError(f"{self.path}: its recorded config does not fit this testbed version ({error})") from None

    def run_info(self) -> dict[str, str]:
        return dict(self.metadata.get("run", {}))

    def metrics(self) -> dict | None:
        """The metrics the run stored when it finished; None for a file cut before that."""
        text = self.metadata.get("metrics", {}).get("json")
        if text is None:
            return None
        metrics = _recorded_json(text, f"{self.path}: its recorded metrics")
        if not isinstance(metrics, dict):
            raise UserError(f"{self.path}: its recorded metrics are damaged (not a JSON table)")
        return metrics

    def outcome(self) -> dict[str, str]:
        return dict(self.metadata.get("outcome", {}))

    def urdf(self) -> str | None:
        data = self.attachments.get("robot.urdf")
        try:
            return None if data is None else data.decode("utf-8")
        except UnicodeDecodeError:
            raise UserError(f"{self.path}: its robot.urdf attachment is not UTF-8 text") from None

    def duration_s(self) -> float:
        ends = [stats.last_ns for stats in self.topics.values() if stats.last_ns is not None]
        return max(ends) / codec.NS_PER_S if ends else 0.0

    def message_count(self) -> int:
        return sum(stats.count for stats in self.topics.values())

    def truncation_note(self) -> str | None:
        if self.truncated is None:
            return None
        return (f"{self.path} is truncated ({self.truncated}); recovered {self.message_count()} messages "
                f"up to t = {self.duration_s():.3f} s")

    def require(self, *topic_names: str, purpose: str) -> None:
        """UserError unless every named topic has messages."""
        for name in topic_names:
            if not self.topics.get(name, TopicStats()).count:
                raise UserError(f"{self.path} has no {name} messages, which {purpose} needs")

    # --- streams ------------------------------------------------------------------------------

    def _decoded(self, topic: str, decode: Callable[[bytes], Any]) -> list:
        return [decode(data) for _, _, data in self.messages.get(topic, [])]

    def samples(self) -> list[Sample]:
        """Every sensor sample, in the order the run loop handed them to the estimator. Samples of
        a sensor plugin come back as instances of its sample class when that can be imported
        (and are left out otherwise: no estimator of this process could know them)."""
        return [sample for block in self.sample_blocks() for sample in block.samples()]

    def sample_blocks(self, block_size: int | None = None) -> Iterator["SampleBlock"]:
        """`samples()` cut into blocks of `block_size` (one block when None), each still columns."""
        order = HandingOrder(self.plugin_sample_classes(), block_size)
        for topic in order.topics:
            order.add(topic, self.messages.get(topic, []))
        return order.blocks()

    def plugin_sample_classes(self) -> dict[str, type]:
        """The sample classes of the sensor plugins' topics that can be imported here."""
        classes = {topic: _importable(metadata.get("sample_class")) for topic, metadata in self.channel_metadata.items()}
        return {topic: sample_class for topic, sample_class in classes.items() if sample_class is not None}

    def estimates(self) -> list[Estimate]:
        return self._decoded(schemas.ESTIMATE.name, codec.decode_estimate)

    def scoring_truth(self) -> ScoringTruth:
        """Per physics step truth for scoring: the steps that have both their pose and their feet."""
        feet_entries = self.messages.get(schemas.TRUTH_FEET.name, [])
        feet_index = {log_ns: k for k, (log_ns, _, _) in enumerate(feet_entries)}
        pose_entries = self.messages.get(schemas.TRUTH_POSE.name, [])
        pairs = [(k, feet_index[log_ns]) for k, (log_ns, _, _) in enumerate(pose_entries) if log_ns in feet_index]
        pose_rows, feet_rows = (list(rows) for rows in zip(*pairs)) if pairs else ([], [])
        positions, quaternions = _decode_poses([pose_entries[k][2] for k in pose_rows])
        feet = message_columns(schemas.FeetTruthMsg, [feet_entries[k][2] for k in feet_rows])
        foot_positions, foot_contact = feet["foot_positions"].rows(6, 3), feet["foot_contact"].rows(6)
        if foot_positions is None or foot_contact is None:
            raise UserError(f"{self.path}: its {schemas.TRUTH_FEET.name} messages do not hold six feet each")
        return ScoringTruth(feet["t"], quaternions, positions, foot_positions, foot_contact)

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t (N,) s, positions (N, 3), quaternions (N, 4)) of /truth/pose."""
        entries = self.messages.get(schemas.TRUTH_POSE.name, [])
        decoded = [codec.decode_pose(data) for _, _, data in entries]
        t = np.array([log_ns for log_ns, _, _ in entries], dtype=np.int64) / codec.NS_PER_S
        positions = np.array([p for p, _ in decoded], dtype=float).reshape(-1, 3)
        return t, positions, np.array([q for _, q in decoded], dtype=float).reshape(-1, 4)

    def truth_states(self) -> list[Truth]:
        return self._decoded(schemas.TRUTH_STATE.name, codec.decode_truth_state)

    def contacts(self) -> list[tuple[float, FootContacts]]:
        return self._decoded(schemas.TRUTH_CONTACTS.name, codec.decode_contacts)

    def supports(self) -> list[codec.SupportSample]:
        return self._decoded(schemas.TRUTH_SUPPORT.name, codec.decode_support)

    def commands(self) -> list[Command]:
        return self._decoded(schemas.COMMAND.name, codec.decode_command)

    def terrain(self) -> codec.TerrainBoxes | None:
        entries = self.messages.get(schemas.TERRAIN.name, [])
        return codec.decode_terrain(entries[0][2]) if entries else None


_SAMPLE_CLASSES = {schemas.IMU.name: ImuSample, schemas.ACCEL_ARRAY.name: AccelSample,
                   schemas.ENCODERS.name: EncoderSample, schemas.FEET.name: FootSample}
_MESSAGE_CLASSES = {topic.name: topic.message_class for topic in schemas.TOPICS}


class HandingOrder:
    """Sensor messages put in the order the run loop handed their samples to the estimator, and
    cut into SampleBlocks as soon as no message still to come can precede them.

    The run loop hands samples over in time order (equal times in the sensor suite's order) and the
    recorder numbers them as it goes: the order is by log time, then sequence, then topic (built-in
    sensors first, in the suite's order). A file written in any order gives the same samples."""

    def __init__(self, plugin_classes: dict[str, type], block_size: int | None):
        self.topics = [*schemas.SENSOR_TOPICS, *plugin_classes]
        self.plugin_classes = plugin_classes
        self.block_size = block_size
        self._log_times = self._sequences = self._topic_indexes = np.empty(0, dtype=np.int64)
        self._payloads: list[bytes] = []

    def add(self, topic: str, entries: Sequence[tuple[int, int, bytes]]) -> None:
        """Messages of `topic` (one of `topics`): (log ns, sequence, data) each."""
        if not entries:
            return
        log_times, sequences, payloads = zip(*entries)
        self._log_times = np.append(self._log_times, np.array(log_times, dtype=np.int64))
        self._sequences = np.append(self._sequences, np.array(sequences, dtype=np.int64))
        self._topic_indexes = np.append(self._topic_indexes, np.full(len(payloads), self.topics.index(topic)))
        self._payloads += payloads

    def blocks(self, before_ns: int | None = None) -> Iterator["SampleBlock"]:
        """The full blocks of the messages logged before `before_ns`, when every message still to
        be added is logged at or after it; with None, the blocks of every message (the last one
        possibly shorter)."""
        order = np.lexsort((self._topic_indexes, self._sequences, self._log_times))
        ready = len(order) if before_ns is None else int(np.searchsorted(self._log_times[order], before_ns))
        size = self.block_size or max(ready, 1)
        handed = 0
        while ready - handed >= size or (before_ns is None and handed < ready):
            rows = order[handed:handed + size]
            yield self._block(rows)
            handed += len(rows)
        kept = order[handed:]
        self._log_times, self._sequences, self._topic_indexes = (
            self._log_times[kept], self._sequences[kept], self._topic_indexes[kept])
        self._payloads = [self._payloads[row] for row in kept.tolist()]

    def _block(self, rows: np.ndarray) -> "SampleBlock":
        topic_indexes = self._topic_indexes[rows]
        parts = []
        for index in np.unique(topic_indexes).tolist():
            positions = np.flatnonzero(topic_indexes == index)
            topic = self.topics[index]
            payloads = [self._payloads[row] for row in rows[positions].tolist()]
            parts.append((topic, positions, _sample_columns(topic, payloads, self.plugin_classes.get(topic))))
        return SampleBlock(len(rows), parts)


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples in handing order, held as columns per topic until `samples()` (so that a
    block passes cheaply between processes)."""
    size: int
    # (topic, positions of its samples in the block, their columns by field or the samples themselves)
    parts: list[tuple[str, np.ndarray, dict[str, Any] | list[Sample]]]

    def samples(self) -> list[Sample]:
        block: list[Any] = [None] * self.size
        for topic, positions, decoded in self.parts:
            samples = decoded if isinstance(decoded, list) else _samples_of_columns(topic, decoded)
            for position, sample in zip(positions.tolist(), samples):
                block[position] = sample
        return block


def _sample_columns(topic: str, payloads: Sequence[bytes], plugin_class: type | None) -> dict[str, Any] | list[Sample]:
    """The field columns of a built-in sensor topic's messages (a row of an array field per
    sample), or the decoded samples of a plugin's topic or of messages whose arrays differ in length."""
    if plugin_class is not None:
        return [codec.decode_plugin_sample(plugin_class, data) for data in payloads]
    columns = {}
    for name, column in message_columns(_MESSAGE_CLASSES[topic], payloads).items():
        columns[name] = column.matrix() if isinstance(column, Ragged) else column
        if columns[name] is None:        # rows of different lengths: no common array
            return [codec.decode_sample(topic, data) for data in payloads]
    return columns


def _samples_of_columns(topic: str, columns: dict[str, Any]) -> list[Sample]:
    sample_class = _SAMPLE_CLASSES[topic]
    values = [columns[field.name] for field in fields(sample_class)]
    return list(map(sample_class, *(column if column.ndim == 2 else column.tolist() for column in values)))


def _decode_poses(payloads: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3), quaternions x, y, z, w (N, 4)) of PoseInFrame messages."""
    rows = np.array(list(map(_pose_row, payloads)), dtype=float).reshape(-1, 7)
    return rows[:, :3].copy(), rows[:, 3:].copy()


def _pose_row(data: bytes) -> tuple[float, ...]:
    """x, y, z, qx, qy, qz, qw of a PoseInFrame."""
    pose = PoseInFrame.FromString(data).pose
    position, orientation = pose.position, pose.orientation
    return position.x, position.y, position.z, orientation.x, orientation.y, orientation.z, orientation.w


def _importable(spec: str | None) -> type | None:
    """The class named MODULE:CLASS, or None when it cannot be imported."""
    if not spec or ":" not in spec:
        return None
    module_name, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module_name), name, None)
    except Exception:   # noqa: BLE001 - any failure to import a plugin means its samples stay unread
        return None


def read_recording(path: str | Path, topics: Collection[str] | None = ALL_TOPICS) -> Recording:
    """Everything readable in the file; the payloads of `topics` only (all when None; a name
    ending in '/' takes every topic under it). With a few topics of a complete file, only the
    chunks that hold them are decompressed and only their messages sliced out (through the file's
    summary and message indexes); a file without a usable summary is read front to back."""
    path = Path(path)
    _check_is_mcap(path)
    if topics is not ALL_TOPICS:
        recording = _read_indexed(path, topics)
        if recording is not None:
            return recording
    recording = Recording(path)
    state = _ReadState(recording, topics)
    with path.open("rb") as stream:
        for record in _records(_stream_reader(stream), recording):
            if not isinstance(record, Chunk):
                state.take(record)
                continue
            try:
                inner = list(_chunk_records(record))
            except Exception as error:  # noqa: BLE001 - a chunk that does not decode ends the readable part
                recording.truncated = _describe(error)
                break
            for item in inner:
                state.take(item)
    return recording


def _read_indexed(path: Path, topics: Collection[str]) -> Recording | None:
    """The recording read through its summary, or None when the file has no complete summary and
    message indexes (a run cut short, another writer) or any part of it does not read."""
    recording = Recording(path)
    state = _ReadState(recording, topics)
    try:
        with path.open("rb") as stream:
            chunk_indexes = _take_summary(stream, state)
            if chunk_indexes is None:
                return None
            for chunk_index in chunk_indexes:
                _take_chunk(stream, chunk_index, state)
    except Exception:   # noqa: BLE001 - whatever does not read through the summary is read front to back
        return None
    return recording


def _take_summary(stream: BinaryIO, state: _ReadState) -> list[ChunkIndex] | None:
    """The schemas, channels, metadata and attachments of the file's summary, taken into `state`;
    returns the chunk indexes, or None when the file has no complete summary with message indexes."""
    reader = make_reader(stream)
    summary = reader.get_summary()
    if summary is None or not summary.chunk_indexes \
            or not all(index.message_index_offsets for index in summary.chunk_indexes):
        return None
    for record in [*summary.schemas.values(), *summary.channels.values(), *reader.iter_metadata(),
                   *reader.iter_attachments()]:
        state.take(record)
    return summary.chunk_indexes


def replay_inputs(path: str | Path, topics: Collection[str], block_size: int) -> Iterator[SampleBlock | ScoringTruth]:
    """What a replay reads: the samples of the sensor `topics` in handing order, in blocks of
    `block_size`, then the scoring truth. Through the file's summary the chunks are read in the order
    of their first log times, and each block is handed over as soon as the chunks read fix it (a
    replay starts after a few chunks); a damaged chunk ends the readable part. A file without a
    usable summary is read whole first."""
    path = Path(path)
    _check_is_mcap(path)
    recording = Recording(path)
    state = _ReadState(recording, frozenset(topics) | SCORING_TOPICS)
    with path.open("rb") as stream:
        try:
            chunk_indexes = _take_summary(stream, state)
        except Exception:   # noqa: BLE001 - read front to back below
            chunk_indexes = None
        if chunk_indexes is not None:
            order = HandingOrder(recording.plugin_sample_classes(), block_size)
            yield from _blocks_chunk_by_chunk(stream, chunk_indexes, state, order)
    if chunk_indexes is None:
        recording = read_recording(path, frozenset(topics) | SCORING_TOPICS)
        yield from recording.sample_blocks(block_size)
    else:
        yield from order.blocks()
    yield recording.scoring_truth()


def _blocks_chunk_by_chunk(stream: BinaryIO, chunk_indexes: list[ChunkIndex], state: _ReadState,
                           order: HandingOrder) -> Iterator[SampleBlock]:
    """The blocks the chunks fix as they are read, in the order of their first log times (the
    messages they leave open stay in `order`); the other wanted messages stay in the recording."""
    messages = state.recording.messages
    chunk_indexes = sorted(chunk_indexes, key=lambda index: (index.message_start_time, index.chunk_start_offset))
    for k, chunk_index in enumerate(chunk_indexes):
        try:
            _take_chunk(stream, chunk_index, state)
        except Exception:   # noqa: BLE001 - a chunk that does not read ends the readable part
            return
        for topic in order.topics:
            if messages.get(topic):
                order.add(topic, messages[topic])
                messages[topic] = []
        if k + 1 < len(chunk_indexes):
            yield from order.blocks(before_ns=chunk_indexes[k + 1].message_start_time)


def _take_chunk(stream: BinaryIO, chunk_index: ChunkIndex, state: _ReadState) -> None:
    """The statistics of every channel of the chunk and the messages of the wanted ones."""
    recording = state.recording
    wanted: dict[str, np.ndarray] = {}
    for channel_id, index_offset in chunk_index.message_index_offsets.items():
        topic = state.channel_topics[channel_id]
        pairs = message_index_pairs(stream, index_offset)
        if len(pairs):
            recording.topics[topic].add_many(len(pairs), int(pairs[:, 0].min()), int(pairs[:, 0].max()))
            if state.wanted(topic):
                wanted[topic] = pairs
    if not wanted:
        return
    records = chunk_records(stream, chunk_index)
    for topic, pairs in wanted.items():
        pairs = pairs[np.argsort(pairs[:, 1], kind="stable")]       # file order
        offsets = pairs[:, 1].astype(np.int64)
        recording.messages[topic] += zip(pairs[:, 0].tolist(), message_sequences(records, offsets).tolist(),
                                         message_payloads(records, offsets))


def chunk_records(stream: BinaryIO, chunk_index: ChunkIndex) -> bytes:
    """The decompressed records of the chunk that `chunk_index` points to, its CRC checked."""
    stream.seek(chunk_index.chunk_start_offset + RECORD_HEADER.size)
    return chunk_data(Chunk.read(ReadDataStream(stream)))


URDF_ELEMENTS = frozenset({"robot", "link", "joint", "visual", "collision", "inertial", "origin", "geometry", "box",
                           "cylinder", "sphere", "capsule", "material", "color", "axis", "parent", "child", "limit",
                           "mass", "inertia", "dynamics", "safety_controller", "calibration", "mimic"})
MAX_URDF_BYTES = 2**20
MAX_URDF_DEPTH = 8


def primitive_urdf(text: str, source: Path | str) -> str:
    """`text` if it is a URDF of primitive shapes only (boxes, cylinders, spheres, as the testbed
    writes), else UserError: a recorded URDF comes from an untrusted file, and a mesh or texture
    would make the viewer read a file of this machine that the URDF names."""
    if len(text) > MAX_URDF_BYTES:
        raise UserError(f"{source}: its robot.urdf is larger than {MAX_URDF_BYTES // 1024} kB")
    if "<!" in text:
        raise UserError(f"{source}: its robot.urdf declares a DOCTYPE or entities, which are not read")
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as error:
        raise UserError(f"{source}: its robot.urdf is not XML ({error})") from None
    if root.tag != "robot":
        raise UserError(f"{source}: its robot.urdf is not a URDF (root element <{root.tag[:40]}>)")
    for element, depth in _elements(root, 1):
        if depth > MAX_URDF_DEPTH:
            raise UserError(f"{source}: its robot.urdf is nested more than {MAX_URDF_DEPTH} deep")
        if element.tag not in URDF_ELEMENTS or "filename" in element.attrib:
            raise UserError(f"{source}: its robot.urdf has a <{str(element.tag)[:40]}> element: only primitive "
                            "geometry (box, cylinder, sphere) is loaded, never a file it names")
    return text


def _elements(element: ElementTree.Element, depth: int) -> Iterator[tuple[ElementTree.Element, int]]:
    yield element, depth
    for child in element:
        yield from _elements(child, depth + 1)


class UnsupportedChunk(ValueError):
    """A chunk this reader does not decompress: an unsupported compression, or larger than MAX_CHUNK_BYTES."""


def chunk_data(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed into at most MAX_CHUNK_BYTES (a compressed chunk that
    expands beyond its declared size is refused, not decompressed), its CRC checked."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise UnsupportedChunk(f"a chunk declares {chunk.uncompressed_size} bytes of records, more than "
                               f"{MAX_CHUNK_BYTES // 2**20} MiB")
    if chunk.compression == "zstd":
        reader = zstandard.ZstdDecompressor().stream_reader(BytesIO(chunk.data))
        data = reader.read(chunk.uncompressed_size + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise UnsupportedChunk(f"a chunk uses the unsupported compression '{chunk.compression[:20]}' "
                               "(this reader reads zstd and uncompressed chunks)")
    if len(data) != chunk.uncompressed_size:
        raise UnsupportedChunk(f"a chunk's records are not the {chunk.uncompressed_size} bytes it declares")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise CRCValidationError(expected=chunk.uncompressed_crc, actual=zlib.crc32(data), record=chunk)
    return data


def _recorded_json(text: Any, what: str) -> Any:
    """Recorded JSON (config, metrics), nested at most MAX_JSON_DEPTH deep; UserError if it is not."""
    if not isinstance(text, str):
        raise UserError(f"{what} is missing")
    depth = max(_running_depth(text), default=0)
    if depth > MAX_JSON_DEPTH:
        raise UserError(f"{what} is damaged (JSON nested {depth} deep, at most {MAX_JSON_DEPTH})")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as error:
        raise UserError(f"{what} is damaged (not JSON: {type(error).__name__})") from None


def _running_depth(text: str) -> Iterator[int]:
    depth = 0
    for character in text:
        if character in "[{":
            depth += 1
            yield depth
        elif character in "]}":
            depth -= 1


def message_index_pairs(stream: BinaryIO, index_offset: int) -> np.ndarray:
    """(N, 2) (log time, offset in the chunk's records) of the messages a Message Index record lists."""
    stream.seek(index_offset)
    _opcode, _length, _channel, pairs_length = MESSAGE_INDEX_HEADER.unpack(stream.read(MESSAGE_INDEX_HEADER.size))
    return np.frombuffer(stream.read(pairs_length), dtype="<u8").reshape(-1, 2)


def _message_field(records: bytes, offsets: np.ndarray, start: int, dtype: str) -> np.ndarray:
    """One fixed-size field, `start` bytes into each of the Message records at `offsets`."""
    size = np.dtype(dtype).itemsize
    as_bytes = np.frombuffer(records, dtype=np.uint8)
    return as_bytes[offsets[:, None] + start + np.arange(size)].copy().view(dtype)[:, 0]


def message_sequences(records: bytes, offsets: np.ndarray) -> np.ndarray:
    """The sequence numbers of the Message records at `offsets` in a chunk's records."""
    return _message_field(records, offsets, RECORD_HEADER.size + 2, "<u4")


def message_payloads(records: bytes, offsets: np.ndarray) -> list[bytes]:
    """The data of the Message records at `offsets` in a chunk's records."""
    ends = offsets + RECORD_HEADER.size + _message_field(records, offsets, 1, "<u8").astype(np.int64)
    starts = offsets + MESSAGE_HEADER.size
    return [records[start:end] for start, end in zip(starts.tolist(), ends.tolist())]


class _ReadState:
    """Routes records into a Recording, keeping the payloads of the wanted topics."""

    def __init__(self, recording: Recording, topics: Collection[str] | None):
        self.recording = recording
        self.topics = topics
        self.channel_topics: dict[int, str] = {}
        self.schema_names: dict[int, str] = {}

    def wanted(self, topic: str) -> bool:
        """A topic among `topics`, or under one of them that ends in '/'."""
        topics = self.topics
        return topics is None or topic in topics or any(name.endswith("/") and topic.startswith(name) for name in topics)

    def take(self, record: Any) -> None:
        recording = self.recording
        if isinstance(record, Message):
            topic = self.channel_topics.get(record.channel_id)
            if topic is None:
                return
            recording.topics[topic].add(record.log_time)
            if self.wanted(topic):
                recording.messages[topic].append((record.log_time, record.sequence, record.data))
        elif isinstance(record, Channel):
            self.channel_topics[record.id] = record.topic
            recording.channel_metadata[record.topic] = dict(record.metadata)
            recording.topics.setdefault(record.topic, TopicStats(self.schema_names.get(record.schema_id, "")))
            recording.messages.setdefault(record.topic, [])
        elif isinstance(record, Schema):
            self.schema_names[record.id] = record.name
        elif isinstance(record, Metadata):
            recording.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Attachment):
            recording.attachments[record.name] = record.data


def _chunk_records(chunk: Chunk) -> Iterator[Any]:
    """The records of a chunk. Messages are sliced out of the decompressed bytes directly, which is
    several times faster than mcap's record-by-record stream parsing; schemas and channels are
    parsed by mcap; other records are skipped."""
    data = chunk_data(chunk)
    size = len(data)
    offset = 0
    while offset < size:
        opcode, length = RECORD_HEADER.unpack_from(data, offset)
        body = offset + RECORD_HEADER.size
        if body + length > size:
            raise ValueError("a chunk record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            _, _, channel_id, sequence, log_time, publish_time = MESSAGE_HEADER.unpack_from(data, offset)
            yield Message(channel_id=channel_id, log_time=log_time, publish_time=publish_time, sequence=sequence,
                          data=data[offset + MESSAGE_HEADER.size:body + length])
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            record_stream = ReadDataStream(BytesIO(data[body:body + length]))
            yield (Schema if opcode == Opcode.SCHEMA else Channel).read(record_stream)
        offset = body + length


def read_description(path: str | Path) -> Recording:
    """Metadata and attachments only. The testbed writes them before the first chunk, so this
    stops there without decompressing any message; other files are read to their end."""
    path = Path(path)
    _check_is_mcap(path)
    recording = Recording(path)
    with path.open("rb") as stream:
        for record in _records(_stream_reader(stream), recording):
            if isinstance(record, Metadata):
                recording.metadata[record.name] = dict(record.metadata)
            elif isinstance(record, Attachment):
                recording.attachments[record.name] = record.data
            elif isinstance(record, Chunk) and "config" in recording.metadata:
                break
    return recording


def _stream_reader(stream: BinaryIO) -> StreamReader:
    return StreamReader(stream, emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES)


def _records(reader: StreamReader, recording: Recording) -> Iterator[Any]:
    """The file's records up to the footer, or up to the first unreadable one (noted)."""
    iterator = reader.records
    while True:
        try:
            record = next(iterator)
        except StopIteration:
            recording.truncated = "it is cut short before its footer"
            return
        except Exception as error:  # noqa: BLE001 - any decoding failure marks the end of the readable part
            recording.truncated = _describe(error)
            return
        yield record
        if isinstance(record, Footer):
            return


def _describe(error: Exception) -> str:
    if isinstance(error, EndOfFile):
        return "it is cut short before its footer"
    if isinstance(error, struct.error) or "past the end" in str(error):
        return "it is cut short in the middle of a record"
    if isinstance(error, CRCValidationError):
        return "a chunk fails its CRC check"
    if isinstance(error, UnsupportedChunk):
        return str(error)
    text = str(error).splitlines()[0] if str(error) else ""
    return f"a record is unreadable ({type(error).__name__}{': ' + text if text else ''})"


def _check_is_mcap(path: Path) -> None:
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if path.is_dir():
        raise UserError(f"{path} is a directory, not an MCAP file")
    if not path.is_file():
        raise UserError(f"{path} is not a regular file (a FIFO or a device is not read)")
    try:
        with path.open("rb") as stream:
            magic = stream.read(len(MCAP_MAGIC))
    except OSError as error:
        raise UserError(f"cannot read {path}: {error.strerror}") from None
    if magic != MCAP_MAGIC:
        raise UserError(f"{path} is not an MCAP file")
