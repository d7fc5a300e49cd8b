"""A flush's messages laid out as MCAP Message records by one compiled call.

What the recorder writes at each flush, step by step: the step's sensor samples, its estimates,
the body pose, the feet and, where the step keeps its tick, the heavy truth (transform, state,
contacts, support, command). The Python encoder (`codec.Encoder` with `datasets.wire`) builds
each message's bytes, then a (channel, log time, data, sequence) tuple per message, then the
record: about 25 us per physics step. Here the batch's values are gathered field by field into
arrays (`np.array` over each field's column: one C loop per field, not per message), and one
numba kernel writes every record, header and protobuf body, into one buffer, in the recorder's
order; `BatchWriter.add_records` adds it to the chunk as it is.

The bytes are those of the Python encoder, field for field (tests/datasets/test_batch_encode.py
compares them over runs with every sample type, absent and empty fields, zeros of both signs,
NaN and support polygons of every size): a singular double written unless its bits are all zero,
a proto3 optional whenever set, a repeated field packed and left out when empty, the Foxglove
pose and transform with their timestamp and each non-zero component.
Values of an unexpected kind (a field that is neither a number nor an array of them, a
negative integer) are not guessed at: `lay_out` returns None and the recorder encodes that flush
with the Python encoder.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from operator import attrgetter, itemgetter
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic

from datasets import codec, schemas, wire
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample

# Layouts of the hexapod messages, by index; the pose and the transform are written apart.
_LAYOUT_NAMES = ("ImuSample", "AccelSample", "EncoderSample", "FootSample", "Estimate", "FeetTruth", "TruthState",
                 "Contacts", "Support", "Command")
IMU, ACCEL, ENCODER, FOOT, ESTIMATE, FEET, STATE, CONTACTS, SUPPORT, COMMAND = range(len(_LAYOUT_NAMES))
SAMPLE_LAYOUTS = {ImuSample: IMU, AccelSample: ACCEL, EncoderSample: ENCODER, FootSample: FOOT}
_TOPICS = {IMU: schemas.IMU, ACCEL: schemas.ACCEL_ARRAY, ENCODER: schemas.ENCODERS, FOOT: schemas.FEET,
           ESTIMATE: schemas.ESTIMATE, FEET: schemas.TRUTH_FEET, STATE: schemas.TRUTH_STATE,
           CONTACTS: schemas.TRUTH_CONTACTS, SUPPORT: schemas.TRUTH_SUPPORT, COMMAND: schemas.COMMAND}
# Field kinds (datasets.wire's): singular double, proto3 optional double, packed doubles, packed
# bools, unsigned integer.
ONE, MAYBE, DOUBLES, BOOLS, UNSIGNED = (wire._DOUBLE_FIELD, wire._OPTIONAL_DOUBLE, wire._DOUBLES, wire._BOOLS,
                                        wire._UNSIGNED)
RECORD_HEADER = 31          # opcode, record length, channel, sequence, log and publish time
_NO_VALUE = np.zeros(0, np.uint8)


class Fields(NamedTuple):
    """The field descriptors of every layout, flat: layout L's fields are first[L]:first[L + 1]."""
    kinds: np.ndarray       # int64
    keys: np.ndarray        # uint8, each field's one-byte key
    first: np.ndarray       # int64


def _fields() -> Fields:
    kinds, keys, first = [], [], [0]
    for name in _LAYOUT_NAMES:
        for kind, key in wire.Layout(schemas.MESSAGES[name])._fields:
            if len(key) != 1:
                raise ValueError(f"{name}: a field key of {len(key)} bytes")     # field numbers up to 15
            kinds.append(kind)
            keys.append(key[0])
        first.append(len(kinds))
    return Fields(np.array(kinds, np.int64), np.array(keys, np.uint8), np.array(first, np.int64))


FIELDS = _fields()


def _prefix(*parts: bytes) -> np.ndarray:
    return np.frombuffer(b"".join(parts), np.uint8).copy()


# The Foxglove messages' constant parts (codec's keys and frames), and the Timestamp's and the
# Vector3 / Quaternion components' keys.
_FOXGLOVE = (
    _prefix(codec._TIMESTAMP), _prefix(codec._SECONDS), _prefix(codec._NANOS),
    _prefix(codec._POSE_FRAME), _prefix(codec._POSE), _prefix(codec._POSITION), _prefix(codec._ORIENTATION),
    _prefix(codec._TRANSFORM_FRAMES), _prefix(codec._TRANSLATION), _prefix(codec._ROTATION),
    np.array([codec._X, codec._Y, codec._Z, codec._W], np.uint8))
if any(len(part) != 1 for part in (_FOXGLOVE[0], _FOXGLOVE[1], _FOXGLOVE[2], _FOXGLOVE[4], _FOXGLOVE[5],
                                   _FOXGLOVE[6], _FOXGLOVE[8], _FOXGLOVE[9])):
    raise ValueError("Foxglove field keys of more than one byte")


class Batch(NamedTuple):
    """`BatchWriter.add_records`' arguments."""
    records: np.ndarray     # uint8
    ends: np.ndarray        # int64, each record's end in `records`
    channels: np.ndarray    # int64
    log_times: np.ndarray   # int64, ns


class Field(NamedTuple):
    payload: np.ndarray     # uint8: the field's bytes in each message, one after the other
    sizes: np.ndarray       # int64: bytes of each message (0: absent; singular numbers 8, written unless zero)


class _Unexpected(Exception):
    """A value the compiled path does not take: the Python encoder writes the flush."""


# --- gathering a batch's values --------------------------------------------------------------

def field(kind: int, column: Any, count: int) -> Field:
    """The bytes of one field of `count` messages, from its values (a sequence, or an array whose
    rows are the messages' values): what `wire.Layout.encode` writes of each, without its key."""
    if kind == DOUBLES or kind == BOOLS:
        dtype = np.float64 if kind == DOUBLES else np.bool_
        try:
            values = np.asarray(column, dtype=dtype, order="C")   # a copy, unless already one array
        except (ValueError, TypeError):         # rows of different sizes, or absent (None) in some
            values = None
        if values is not None and values.ndim >= 2 and len(values) == count:
            size = values.nbytes // count if count else 0
            return Field(values.reshape(-1).view(np.uint8), np.full(count, size, np.int64))
        parts = [_NO_VALUE if value is None else np.ascontiguousarray(value, dtype=dtype).reshape(-1).view(np.uint8)
                 for value in column]
        if len(parts) != count:
            raise _Unexpected("a column of another length")
        sizes = np.array([len(part) for part in parts], np.int64)
        return Field(np.concatenate(parts) if parts else _NO_VALUE, sizes)
    if count == 0:
        return Field(_NO_VALUE, np.zeros(0, np.int64))
    if kind == UNSIGNED:
        values = np.array(column)
        if (values.shape != (count,) or values.dtype.kind not in "iu" or values.min() < 0
                or values.max() >= 2**63):
            raise _Unexpected("an unsigned field that is not of non-negative integers")
        return Field(values.astype("<i8").view(np.uint8), np.full(count, 8, np.int64))
    if type(column) is np.ndarray:
        values = column
    else:
        values = np.array(column, np.float64)       # None becomes NaN: looked for only where there is a NaN
        if values.shape == (count,) and np.isnan(values).any():
            absent = [value is None for value in column]
            if True in absent:
                if kind == ONE:
                    raise _Unexpected("a singular double without a value")
                values = np.array([value for value in column if value is not None], np.float64).reshape(-1)
                sizes = np.where(absent, 0, 8).astype(np.int64)
                if len(values) != count - sum(absent):
                    raise _Unexpected("an optional double that is not one number")
                return Field(values.view(np.uint8), sizes)
    if values.shape != (count,) or values.dtype != np.float64:
        raise _Unexpected("a singular double field that is not one number per message")
    return Field(np.ascontiguousarray(values).view(np.uint8), np.full(count, 8, np.int64))


def _rows(column: Any, dtype, count: int):
    """The column as one array of a row per message if its values are of one shape (what
    `field` makes of it), else the column as it is."""
    try:
        values = np.array(column, dtype=dtype)
    except (ValueError, TypeError):
        return column
    return values if values.ndim >= 2 and len(values) == count else column


def layout_fields(layout: int, columns: list, count: int) -> list[Field]:
    kinds = FIELDS.kinds[FIELDS.first[layout]:FIELDS.first[layout + 1]].tolist()
    if len(columns) != len(kinds):
        raise _Unexpected("a message without all its fields")
    return [field(kind, column, count) for kind, column in zip(kinds, columns)]


_NAMES = [tuple(name for name, _, _ in schemas.MESSAGES[name]) for name in _LAYOUT_NAMES]
_GETTERS = [attrgetter(*names) for names in _NAMES]          # every message has two fields or more
_ITEM_GETTERS = [itemgetter(*names) for names in _NAMES]
_CONTACT_ARRAYS = codec._CONTACT_ARRAYS


def _columns_of(layout: int, items: list) -> list:
    """Each field's values in `items`, objects with the fields as attributes, all of one type:
    named tuples whose fields start with the message's are transposed; the fields of plain
    dataclasses are read from their instances' dicts (40 % cheaper than as attributes)."""
    names = _NAMES[layout]
    if not items:
        return [()] * len(names)
    kind = type(items[0])
    if len(set(map(type, items))) == 1:
        if getattr(kind, "_fields", ())[:len(names)] == names:
            return list(zip(*items))[:len(names)]
        if _fields_in_instance_dict(kind, names):
            return list(zip(*map(_ITEM_GETTERS[layout], map(vars, items))))
    return list(zip(*map(_GETTERS[layout], items)))


@lru_cache(maxsize=None)
def _fields_in_instance_dict(kind: type, names: tuple[str, ...]) -> bool:
    """Whether an instance's attributes `names` are the values in its __dict__: a dataclass with
    those fields, no slots, no descriptor of those names, the default attribute lookup."""
    if not dataclasses.is_dataclass(kind) or kind.__getattribute__ is not object.__getattribute__:
        return False
    if any("__slots__" in vars(base) for base in kind.__mro__[:-1]):
        return False
    fields = {field.name for field in dataclasses.fields(kind)}
    return all(name in fields and not hasattr(type(getattr(kind, name, None)), "__get__") for name in names)


class Gathered(NamedTuple):
    """A flush's values, laid out for `_write_records`."""
    payload: np.ndarray         # uint8: every field's bytes, layout by layout, field by field
    payload_start: np.ndarray   # int64 per field: where its bytes start in `payload`
    sizes: np.ndarray           # int64: the fields' per-message sizes, field by field
    sizes_start: np.ndarray     # int64 per field: where its sizes start in `sizes`
    log_ns: np.ndarray          # int64: each hexapod message's log time, layout by layout
    log_start: np.ndarray       # int64 per layout: where its log times start in `log_ns`


def gather(per_layout: list[tuple[list[Field], np.ndarray]]) -> Gathered:
    """Per layout, in order: its fields and its messages' log times."""
    fields = [each for layout_fields_, _ in per_layout for each in layout_fields_]
    payload_sizes = np.array([len(each.payload) for each in fields], np.int64)
    size_counts = np.array([len(each.sizes) for each in fields], np.int64)
    log_counts = np.array([len(log_ns) for _, log_ns in per_layout], np.int64)
    return Gathered(
        np.concatenate([each.payload for each in fields]) if fields else _NO_VALUE,
        np.concatenate(([0], np.cumsum(payload_sizes)[:-1])).astype(np.int64),
        np.concatenate([each.sizes for each in fields]).astype(np.int64),
        np.concatenate(([0], np.cumsum(size_counts)[:-1])).astype(np.int64),
        np.concatenate([log_ns for _, log_ns in per_layout]).astype(np.int64),
        np.concatenate(([0], np.cumsum(log_counts)[:-1])).astype(np.int64))


def to_ns(times: np.ndarray) -> np.ndarray:
    """`codec.to_ns_many`, as an array."""
    return np.rint(times * codec.NS_PER_S).astype(np.int64)


def _times(fields: list[Field]) -> np.ndarray:
    """The log times of messages whose first field is `t` (every hexapod message)."""
    return to_ns(fields[0].payload.view(np.float64))


# --- the recorder's batch --------------------------------------------------------------------

def lay_out(steps: list, channel_of: np.ndarray, first_sequence: int) -> Batch | None:
    """The records of a flush's steps (`datasets.recorder._Step`), in the recorder's order;
    `channel_of` gives the channel of each layout, then of the pose and of the transform. None if
    a value is of a kind the compiled path does not take."""
    try:
        return _lay_out(steps, channel_of, first_sequence)
    except Exception:       # _Unexpected, or numpy refusing a value: the Python encoder's own error, if any
        return None


def _lay_out(steps: list, channel_of: np.ndarray, first_sequence: int) -> Batch:
    count = len(steps)
    times, positions, quaternions, feet, contacts, samples_of, estimates_of, ticks = (
        zip(*steps) if steps else ((),) * 8)
    truth_t = np.array(times, np.float64)
    if truth_t.shape != (count,):
        raise _Unexpected("step times")
    truth_ns = to_ns(truth_t)
    per_layout: list[tuple[list[Field], np.ndarray]] = []

    samples = [sample for step_samples in samples_of for sample in step_samples]
    sample_counts = np.array([len(step_samples) for step_samples in samples_of], np.int64)
    try:
        codes = np.array([SAMPLE_LAYOUTS[type(sample)] for sample in samples], np.int64)
    except KeyError:
        raise _Unexpected("a sample type without a layout") from None
    for layout in (IMU, ACCEL, ENCODER, FOOT):
        of_layout = [samples[index] for index in np.flatnonzero(codes == layout).tolist()]
        fields = layout_fields(layout, _columns_of(layout, of_layout), len(of_layout))
        per_layout.append((fields, _times(fields)))

    estimates = [estimate for step_estimates in estimates_of for estimate in step_estimates]
    estimate_counts = np.array([len(step_estimates) for step_estimates in estimates_of], np.int64)
    fields = layout_fields(ESTIMATE, _columns_of(ESTIMATE, estimates), len(estimates))
    per_layout.append((fields, _times(fields)))

    poses = np.empty((count, 7), np.float64)
    try:
        poses[:, :3] = np.array(positions, np.float64).reshape(count, 3)
        poses[:, 3:] = np.array(quaternions, np.float64).reshape(count, 4)
    except ValueError:
        raise _Unexpected("a pose that is not a position and a quaternion") from None
    feet_values, contact_values = _rows(feet, np.float64, count), _rows(contacts, np.bool_, count)
    fields = layout_fields(FEET, [truth_t, feet_values, contact_values], count)
    per_layout.append((fields, truth_ns))

    heavy = [tick for tick in ticks if tick is not None]
    heavy_steps = np.array([tick is not None for tick in ticks], np.bool_)
    truths = [tick.truth for tick in heavy]
    heavy_t = truth_t[heavy_steps]
    heavy_ns = truth_ns[heavy_steps]
    # the state's position, feet and contact flags are the step's own (the same arrays): taken
    # from the pose's and the feet's values where those are one array
    columns = _columns_of(STATE, truths)
    columns[0] = heavy_t
    columns[1] = poses[heavy_steps, :3]
    if type(feet_values) is np.ndarray:
        columns[9] = feet_values[heavy_steps]
    if type(contact_values) is np.ndarray:
        columns[12] = contact_values[heavy_steps]
    fields = layout_fields(STATE, columns, len(heavy))
    per_layout.append((fields, heavy_ns))
    contact_columns = (list(zip(*map(_CONTACT_ARRAYS, [tick.contacts for tick in heavy]))) if heavy
                       else [()] * (FIELDS.first[CONTACTS + 1] - FIELDS.first[CONTACTS] - 1))
    fields = layout_fields(CONTACTS, [heavy_t, *contact_columns], len(heavy))
    per_layout.append((fields, heavy_ns))
    com = np.array([truth.com_position for truth in truths], np.float64).reshape(len(heavy), -1) if heavy \
        else np.zeros((0, 2))
    if com.shape[1] < 2:
        raise _Unexpected("a centre of mass without x and y")
    support_columns = [heavy_t, [tick.support_polygon for tick in heavy], com[:, :2],
                       np.array([float(tick.stability_margin) for tick in heavy], np.float64)]
    fields = layout_fields(SUPPORT, support_columns, len(heavy))
    per_layout.append((fields, heavy_ns))
    fields = layout_fields(COMMAND, _columns_of(COMMAND, [tick.command for tick in heavy]), len(heavy))
    per_layout.append((fields, _times(fields)))

    if count and truth_ns.min() < 0:
        raise _Unexpected("a time before 0")
    gathered = gather(per_layout)
    records, ends, channels, log_times = _write_records(
        sample_counts, codes, estimate_counts, heavy_steps, first_sequence, FIELDS.kinds, FIELDS.keys,
        FIELDS.first, gathered.payload, gathered.payload_start, gathered.sizes, gathered.sizes_start,
        gathered.log_ns, gathered.log_start, channel_of, poses.view(np.uint8).reshape(count, 56), truth_ns,
        *_FOXGLOVE)
    return Batch(records, ends, channels, log_times)


# --- the kernel ------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _varint(out, position, value):
    while value >= 128:
        out[position] = (value & 0x7F) | 0x80
        position += 1
        value >>= 7
    out[position] = value
    return position + 1


@njit(cache=True, nogil=True)
def _little_endian(out, position, value, size):
    for index in range(size):
        out[position + index] = (value >> (8 * index)) & 0xFF
    return position + size


@intrinsic
def _memcpy(typing_context, destination, destination_at, source, source_at, size):
    """LLVM's memcpy of `size` bytes between two uint8 arrays, without bounds checks. (A byte
    loop is not vectorised, the arrays might overlap; a slice assignment copies its source first.)"""
    signature = types.void(destination, destination_at, source, source_at, size)

    def codegen(context, builder, signature, args):
        destination_array = context.make_array(signature.args[0])(context, builder, args[0])
        source_array = context.make_array(signature.args[2])(context, builder, args[2])
        cgutils.raw_memcpy(builder, builder.gep(destination_array.data, [args[1]]),
                           builder.gep(source_array.data, [args[3]]), args[4], 1)
    return signature, codegen


@njit(cache=True, nogil=True)
def _copy(out, position, data):
    for index in range(len(data)):
        out[position + index] = data[index]
    return position + len(data)


@njit(cache=True, nogil=True)
def _copy_from(out, position, data, start, size):
    """data[start:start + size] to out[position:]; the caller keeps both within their arrays."""
    _memcpy(out, position, data, start, size)
    return position + size


@njit(cache=True, nogil=True)
def _is_zero(data, start, size):
    for index in range(start, start + size):
        if data[index] != 0:
            return False
    return True


@njit(cache=True, nogil=True)
def _header(out, position, channel, sequence, log_time):
    """A Message record's header, its length left to `_close_record`."""
    out[position] = 0x05
    position = _little_endian(out, position + 9, channel, 2)
    position = _little_endian(out, position, sequence, 4)
    position = _little_endian(out, position, log_time, 8)
    return _little_endian(out, position, log_time, 8)


@njit(cache=True, nogil=True)
def _close_record(out, start, end):
    _little_endian(out, start + 1, end - start - 9, 8)


@njit(cache=True, nogil=True)
def _hexapod_body(out, position, layout, index, kinds, keys, first, payload, offsets, sizes, sizes_start):
    for field in range(first[layout], first[layout + 1]):
        kind = kinds[field]
        size = sizes[sizes_start[field] + index]
        start = offsets[sizes_start[field] + index]
        if size == 0:
            continue
        if kind == 0:           # singular double: left out when its bits are all zero
            if _is_zero(payload, start, 8):
                continue
            out[position] = keys[field]
            position = _copy_from(out, position + 1, payload, start, 8)
        elif kind == 1:         # optional double, set
            out[position] = keys[field]
            position = _copy_from(out, position + 1, payload, start, 8)
        elif kind == 4:         # unsigned integer (int64 little-endian): left out when zero
            value = 0
            for byte in range(8):
                value |= np.int64(payload[start + byte]) << (8 * byte)
            if value == 0:
                continue
            out[position] = keys[field]
            position = _varint(out, position + 1, value)
        else:                   # packed doubles or bools
            out[position] = keys[field]
            position = _varint(out, position + 1, size)
            position = _copy_from(out, position, payload, start, size)
    return position


@njit(cache=True, nogil=True)
def _components(out, position, key, data, start, count, component_keys):
    """A length-delimited foxglove.Vector3 or Quaternion: each double whose bits are not zero."""
    out[position] = key
    length_at = position + 1
    position += 2               # at most 4 x 9 bytes: a one-byte length
    for component in range(count):
        at = start + 8 * component
        if not _is_zero(data, at, 8):
            out[position] = component_keys[component]
            position = _copy_from(out, position + 1, data, at, 8)
    out[length_at] = position - length_at - 1
    return position


@njit(cache=True, nogil=True)
def _timestamp(out, position, t_ns, timestamp_key, seconds_key, nanos_key):
    seconds, nanos = t_ns // 1_000_000_000, t_ns % 1_000_000_000
    out[position] = timestamp_key[0]
    length_at = position + 1
    position += 2               # at most 1 + 10 + 1 + 5 bytes: a one-byte length
    if seconds:
        out[position] = seconds_key[0]
        position = _varint(out, position + 1, seconds)
    if nanos:
        out[position] = nanos_key[0]
        position = _varint(out, position + 1, nanos)
    out[length_at] = position - length_at - 1
    return position


@njit(cache=True, nogil=True)
def _pose_body(out, position, pose, t_ns, timestamp_key, seconds_key, nanos_key, pose_frame, pose_key, position_key,
               orientation_key, component_keys):
    """A foxglove.PoseInFrame: timestamp, frame, pose (position, orientation)."""
    position = _timestamp(out, position, t_ns, timestamp_key, seconds_key, nanos_key)
    position = _copy(out, position, pose_frame)
    out[position] = pose_key[0]
    length_at = position + 1
    position += 2               # at most 2 + 27 + 2 + 36 bytes: a one-byte length
    position = _components(out, position, position_key[0], pose, 0, 3, component_keys)
    position = _components(out, position, orientation_key[0], pose, 24, 4, component_keys)
    out[length_at] = position - length_at - 1
    return position


@njit(cache=True, nogil=True)
def _transform_body(out, position, pose, t_ns, timestamp_key, seconds_key, nanos_key, frames, translation_key,
                    rotation_key, component_keys):
    """A foxglove.FrameTransform: timestamp, parent and child frames, translation, rotation."""
    position = _timestamp(out, position, t_ns, timestamp_key, seconds_key, nanos_key)
    position = _copy(out, position, frames)
    position = _components(out, position, translation_key[0], pose, 0, 3, component_keys)
    return _components(out, position, rotation_key[0], pose, 24, 4, component_keys)


@njit(cache=True, nogil=True)
def _write_records(sample_counts, codes, estimate_counts, heavy_steps, first_sequence, kinds, keys, first, payload,
                   payload_start, sizes, sizes_start, log_ns, log_start, channel_of, poses, truth_ns, timestamp_key,
                   seconds_key, nanos_key, pose_frame, pose_key, position_key, orientation_key, transform_frames,
                   translation_key, rotation_key, component_keys):
    steps = len(sample_counts)
    heavy_count = 0
    for step in range(steps):
        heavy_count += heavy_steps[step]
    messages = len(codes) + np.sum(estimate_counts) + 2 * steps + 5 * heavy_count
    # every message's values are there (the copies below are not bounds-checked)
    expected = np.zeros(len(log_start), np.int64)
    for code in codes:
        if code < 0 or code > 3:
            raise ValueError("a sample code that is not a sample layout")
        expected[code] += 1
    expected[4], expected[5] = np.sum(estimate_counts), steps
    expected[6:] = heavy_count
    for layout in range(len(log_start)):
        end = log_start[layout + 1] if layout + 1 < len(log_start) else len(log_ns)
        if end - log_start[layout] != expected[layout]:
            raise ValueError("a layout without the values of each of its messages")
        for field in range(first[layout], first[layout + 1]):
            end = sizes_start[field + 1] if field + 1 < len(sizes_start) else len(sizes)
            if end - sizes_start[field] != expected[layout]:
                raise ValueError("a field without the size of each of its messages")
    if len(poses) != steps or len(truth_ns) != steps or (steps and poses.shape[1] != 56):
        raise ValueError("a step without its pose")
    # each field's bytes in each message: the sizes' running sum from the field's start
    offsets = np.empty_like(sizes)
    for field in range(len(payload_start)):
        end = sizes_start[field + 1] if field + 1 < len(sizes_start) else len(sizes)
        running = payload_start[field]
        for at in range(sizes_start[field], end):
            if sizes[at] < 0:
                raise ValueError("a field of negative size")
            offsets[at] = running
            running += sizes[at]
        if running != (payload_start[field + 1] if field + 1 < len(payload_start) else len(payload)):
            raise ValueError("a field whose sizes do not add up to its bytes")      # the copies stay in payload    # every field at most its key and a 10-byte varint more than its bytes; a pose or transform
    # at most 30 + 72 bytes and its frames
    bound = (len(payload) + messages * RECORD_HEADER + len(sizes) * 11
             + steps * (2 * (110 + len(pose_frame) + len(transform_frames))))
    out = np.empty(bound, np.uint8)
    ends = np.empty(messages, np.int64)
    channels = np.empty(messages, np.int64)
    log_times = np.empty(messages, np.int64)
    next_index = np.zeros(len(log_start), np.int64)
    position = 0
    message = 0
    sample = 0
    heavy = 0
    for step in range(steps):
        # samples, then estimates
        for entry in range(sample_counts[step] + estimate_counts[step]):
            if entry < sample_counts[step]:
                layout = codes[sample]
                sequence = first_sequence + sample
                sample += 1
            else:
                layout = 4
                sequence = 0
            index = next_index[layout]
            next_index[layout] += 1
            log_time = log_ns[log_start[layout] + index]
            start = position
            position = _header(out, position, channel_of[layout], sequence, log_time)
            position = _hexapod_body(out, position, layout, index, kinds, keys, first, payload, offsets, sizes,
                                     sizes_start)
            _close_record(out, start, position)
            ends[message], channels[message], log_times[message] = position, channel_of[layout], log_time
            message += 1
        # the pose, then the feet
        start = position
        position = _header(out, position, channel_of[10], 0, truth_ns[step])
        position = _pose_body(out, position, poses[step], truth_ns[step], timestamp_key, seconds_key, nanos_key,
                              pose_frame, pose_key, position_key, orientation_key, component_keys)
        _close_record(out, start, position)
        ends[message], channels[message], log_times[message] = position, channel_of[10], truth_ns[step]
        message += 1
        start = position
        position = _header(out, position, channel_of[5], 0, truth_ns[step])
        position = _hexapod_body(out, position, 5, step, kinds, keys, first, payload, offsets, sizes, sizes_start)
        _close_record(out, start, position)
        ends[message], channels[message], log_times[message] = position, channel_of[5], truth_ns[step]
        message += 1
        if not heavy_steps[step]:
            continue
        # the heavy truth: transform, state, contacts, support, command
        start = position
        position = _header(out, position, channel_of[11], 0, truth_ns[step])
        position = _transform_body(out, position, poses[step], truth_ns[step], timestamp_key, seconds_key, nanos_key,
                                   transform_frames, translation_key, rotation_key, component_keys)
        _close_record(out, start, position)
        ends[message], channels[message], log_times[message] = position, channel_of[11], truth_ns[step]
        message += 1
        for layout in range(6, 10):
            log_time = log_ns[log_start[layout] + heavy]
            start = position
            position = _header(out, position, channel_of[layout], 0, log_time)
            position = _hexapod_body(out, position, layout, heavy, kinds, keys, first, payload, offsets, sizes,
                                     sizes_start)
            _close_record(out, start, position)
            ends[message], channels[message], log_times[message] = position, channel_of[layout], log_time
            message += 1
        heavy += 1
    if position > bound or message != messages:
        raise ValueError("records past their bound")
    return out[:position], ends, channels, log_times


def channels_of(channels: dict[str, int]) -> np.ndarray:
    """`lay_out`'s `channel_of` from the dataset's channel ids by topic."""
    return np.array([channels[_TOPICS[layout].name] for layout in range(len(_LAYOUT_NAMES))]
                    + [channels[schemas.TRUTH_POSE.name], channels[schemas.TF.name]], np.int64)
