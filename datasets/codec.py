"""Conversion between the testbed's objects and the dataset's protobuf messages, both ways.

Encoding goes through the message classes (`datasets.schemas`, Foxglove's) and protobuf's
`SerializeToString`; decoding through `FromString`. Every float is a float64, so decoding gives
back bit-identical arrays (NaN payloads included).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, fields
from operator import attrgetter
from typing import Any, NamedTuple
from xml.etree import ElementTree

import numpy as np
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pb2
from scipy.spatial.transform import Rotation

from datasets import schemas
from datasets.links import LinkTree
from estimators.base import Estimate
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from testbed.world.contact import FootContacts
from testbed.control.command import Command
from testbed.model.truth import Truth
from testbed.runtime.recording import Tick

WORLD_FRAME = "world"
BODY_FRAME = "body"         # the URDF's root link
NS_PER_S = 1_000_000_000


def to_ns(t: float) -> int:
    """Simulation seconds to MCAP nanoseconds (log and publish time)."""
    return int(round(t * NS_PER_S))


@dataclass(frozen=True)
class SupportSample:
    t: float
    polygon: np.ndarray          # (K, 2) m, world x, y of the stance feet's convex hull
    com_projection: np.ndarray   # (2,) m, world x, y of the centre of mass
    stability_margin: float      # m


@dataclass(frozen=True)
class TerrainBoxes:
    centers: np.ndarray          # (N, 3) m, world
    sizes: np.ndarray            # (N, 3) m, full edge lengths
    quaternions: np.ndarray      # (N, 4) x, y, z, w, world_from_box


def _flat(values: Any) -> list:
    """An array of any shape (or a sequence) as the flat, row-major list a repeated field takes."""
    return values.ravel().tolist() if type(values) is np.ndarray else np.ravel(values).tolist()


def repeated_fields(message_class: type) -> dict[str, bool]:
    """Field name -> whether it is repeated, in field order, as descriptor.proto states them (the
    label means the same on every protobuf version, where FieldDescriptor's own attributes differ)."""
    described = descriptor_pb2.DescriptorProto()
    message_class.DESCRIPTOR.CopyToProto(described)
    repeated = descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED
    return {field.name: field.label == repeated for field in described.field}


class MessageEncoder:
    """Serialises messages of one protobuf class of scalar and repeated scalar fields (the
    `hexapod` messages) from their field values, in the order the descriptor lists the fields
    (`field_names`): `encode` takes the values in that order, `encode_fields_of` reads the
    attributes named as the fields, `encode_rows` takes the fields' columns (`Columns`). Arrays of
    any shape go to repeated fields row-major; None leaves a field absent (an unset proto3
    `optional`, an empty repeated field).

    One message object is filled again for each call, its repeated fields' containers looked up
    once: cheaper than building a new message each time."""

    def __init__(self, message_class: type):
        message = self._message = message_class()
        repeated = repeated_fields(message_class)
        self.field_names = tuple(repeated)
        # (name, the repeated field's container or None for a singular field)
        self._fields = [(name, getattr(message, name) if repeated[name] else None) for name in repeated]
        getter = attrgetter(*self.field_names)
        self._values_of = getter if len(self._fields) > 1 else lambda item: (getter(item),)

    def encode_fields_of(self, item: Any) -> bytes:
        return self.encode(self._values_of(item))

    def encode(self, values: Any) -> bytes:
        return self._serialise([value if value is None or repeated is None else _flat(value)
                                for (_, repeated), value in zip(self._fields, values)])

    def encode_rows(self, columns: "Columns") -> list[bytes]:
        """The messages of every row of `columns`, which holds a column for each field."""
        field_rows = [columns.rows(name) for name in self.field_names]
        return [self._serialise(values) for values in zip(*field_rows)]

    def _serialise(self, values: Any) -> bytes:
        """The message of these values, repeated fields' values given as flat lists."""
        message = self._message
        for (name, repeated), value in zip(self._fields, values):
            if repeated is not None:
                repeated[:] = () if value is None else value
            elif value is None:
                message.ClearField(name)
            else:
                setattr(message, name, value)
        return message.SerializeToString()


SAMPLE_TOPICS = {ImuSample: schemas.IMU, AccelSample: schemas.ACCEL_ARRAY, EncoderSample: schemas.ENCODERS,
                 FootSample: schemas.FEET}


def sample_topic(kind: type) -> schemas.Topic:
    """The topic of a type of sensor sample: a sensor plugin's type gets its own
    (`schemas.sample_topic`; TypeError if it cannot be recorded)."""
    topic = SAMPLE_TOPICS.get(kind)
    return topic if topic is not None else schemas.sample_topic(kind)


# The Contacts message: t, then the FootContacts arrays of its other fields' names.
_CONTACT_ARRAYS = attrgetter(*(name for name, _, _ in schemas.MESSAGES["Contacts"][1:]))


class Encoder:
    """Serialises the testbed's objects into the dataset's messages: one at a time, or a
    handover's ticks at once from their columns (`messages`)."""

    def __init__(self) -> None:
        encoders = {name: MessageEncoder(message_class) for name, message_class in schemas.CLASSES.items()}
        self._samples = {kind: (topic, encoders[topic.message_class.DESCRIPTOR.name])
                         for kind, topic in SAMPLE_TOPICS.items()}
        self._estimate, self._feet, self._state = encoders["Estimate"], encoders["FeetTruth"], encoders["TruthState"]
        self._contacts, self._support, self._command = encoders["Contacts"], encoders["Support"], encoders["Command"]
        self._pose = PoseInFrame(frame_id=WORLD_FRAME)
        self._pose_parts = (self._pose.timestamp, self._pose.pose.position, self._pose.pose.orientation)
        self._links: LinkTree | None = None
        self._transforms = FrameTransforms()
        self._transform = self._transforms.transforms.add(parent_frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME)
        self._transform_parts = (self._transform.timestamp, self._transform.translation, self._transform.rotation)

    def describe_robot(self, urdf: str) -> None:
        """Publish every link's frame on /tf from now on: the joints of `urdf` (`links.LinkTree`),
        each at the joint positions of the truth state. A URDF that is not the hexapod's (a
        foreign recording replayed into a new file) leaves /tf with the body's frame alone."""
        try:
            self._links = LinkTree.from_urdf(urdf)
        except (ElementTree.ParseError, ValueError):
            return
        for joint in self._links.joints:
            transform = self._transforms.transforms.add(parent_frame_id=joint.parent, child_frame_id=joint.child)
            transform.translation.x, transform.translation.y, transform.translation.z = joint.translation

    def sample(self, sample: Sample) -> tuple[str, bytes]:
        """(topic name, message bytes) of one sensor sample."""
        topic, encoder = self._sample_encoder(type(sample))
        return topic.name, encoder.encode_fields_of(sample)

    def estimate(self, estimate: Estimate) -> bytes:
        return self._estimate.encode_fields_of(estimate)

    def pose(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        return self._stamped_pose(self._pose, self._pose_parts, t_ns, _flat(position), _flat(quaternion))

    def feet(self, truth: Truth) -> bytes:
        return self._feet.encode_fields_of(truth)

    def transforms(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray,
                   joint_positions: np.ndarray | None = None) -> bytes:
        """The /tf message: world -> body, and with `describe_robot` each joint's parent -> child link."""
        return self._frame_transforms(t_ns, _flat(position), _flat(quaternion),
                                      None if joint_positions is None else _flat(joint_positions))

    def truth_state(self, truth: Truth) -> bytes:
        return self._state.encode_fields_of(truth)

    def contacts(self, t: float, contacts: FootContacts) -> bytes:
        return self._contacts.encode((t, *_CONTACT_ARRAYS(contacts)))

    def support(self, t: float, polygon: np.ndarray, com_projection: np.ndarray, margin: float) -> bytes:
        return self._support.encode((t, polygon, com_projection, float(margin)))

    def command(self, command: Command) -> bytes:
        return self._command.encode_fields_of(command)

    def messages(self, ticks: "TickColumns") -> Iterator[tuple[schemas.Topic, int, bytes, int]]:
        """(topic, log time ns, data, sequence) of every message of `ticks`, in file order: each
        tick's samples (numbered on from `first_sequence`), estimates, pose and feet, then at a
        heavy tick its transform, state, contacts, support and command."""
        samples = [self._sample_messages(kind, columns) for kind, columns in zip(ticks.sample_types, ticks.samples)]
        sample_kinds = iter(ticks.sample_kinds.tolist())
        estimates = self._stamped_rows(self._estimate, ticks.estimates)
        every_tick = self._every_tick_messages(ticks.truth)
        heavy = self._heavy_messages(ticks)
        sequence = ticks.first_sequence
        for sample_count, estimate_count, is_heavy in zip(ticks.samples_per_tick.tolist(),
                                                           ticks.estimates_per_tick.tolist(), ticks.heavy.tolist()):
            for _ in range(sample_count):
                topic, log_ns, data = next(samples[next(sample_kinds)])
                yield topic, log_ns, data, sequence
                sequence += 1
            for _ in range(estimate_count):
                log_ns, data = next(estimates)
                yield schemas.ESTIMATE, log_ns, data, 0
            yield from next(every_tick)
            if is_heavy:
                yield from next(heavy)

    def _sample_encoder(self, kind: type) -> tuple[schemas.Topic, MessageEncoder]:
        if kind not in self._samples:
            topic = sample_topic(kind)
            self._samples[kind] = (topic, MessageEncoder(topic.message_class))
        return self._samples[kind]

    def _sample_messages(self, kind: type, columns: "Columns") -> Iterator[tuple[schemas.Topic, int, bytes]]:
        topic, encoder = self._sample_encoder(kind)
        return ((topic, log_ns, data) for log_ns, data in self._stamped_rows(encoder, columns))

    @staticmethod
    def _stamped_rows(encoder: MessageEncoder, columns: "Columns") -> Iterator[tuple[int, bytes]]:
        """(log time ns, data) of each row, its log time that of its field `t`."""
        return zip(map(to_ns, columns.rows("t")), encoder.encode_rows(columns))

    def _every_tick_messages(self, truth: "Columns") -> Iterator[tuple]:
        """Each tick's pose and feet messages."""
        feet = self._feet.encode_rows(truth)
        for t, position, quaternion, feet_data in zip(truth.rows("t"), truth.rows("body_position"),
                                                        truth.rows("quaternion"), feet):
            t_ns = to_ns(t)
            yield ((schemas.TRUTH_POSE, t_ns, self._stamped_pose(self._pose, self._pose_parts, t_ns, position,
                                                                  quaternion), 0),
                   (schemas.TRUTH_FEET, t_ns, feet_data, 0))

    def _heavy_messages(self, ticks: "TickColumns") -> Iterator[tuple]:
        """Each heavy tick's transform, state, contacts, support and command messages."""
        state = ticks.state
        rows = zip(state.rows("t"), state.rows("body_position"), state.rows("quaternion"), state.rows("joint_positions"),
                   self._state.encode_rows(state), self._contacts.encode_rows(ticks.contacts),
                   self._support.encode_rows(ticks.support), self._stamped_rows(self._command, ticks.commands))
        for t, position, quaternion, joints, state_data, contacts_data, support_data, (command_ns, command_data) in rows:
            t_ns = to_ns(t)
            transform = self._frame_transforms(t_ns, position, quaternion, joints)
            yield ((schemas.TF, t_ns, transform, 0), (schemas.TRUTH_STATE, t_ns, state_data, 0),
                   (schemas.TRUTH_CONTACTS, t_ns, contacts_data, 0), (schemas.TRUTH_SUPPORT, t_ns, support_data, 0),
                   (schemas.COMMAND, command_ns, command_data, 0))

    def _frame_transforms(self, t_ns: int, position: list, quaternion: list, joint_positions: list | None) -> bytes:
        """Fill and serialise the FrameTransforms message: the body's pose, then (with a link
        tree) each joint's rotation, all stamped `t_ns`."""
        joints = self._transforms.transforms[1:]
        if self._links is not None and joint_positions is not None:
            seconds, nanos = divmod(t_ns, NS_PER_S)
            for transform, rotation in zip(joints, self._links.rotations(joint_positions)):
                transform.timestamp.seconds, transform.timestamp.nanos = seconds, nanos
                transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w = rotation
        return self._stamped_pose(self._transforms, self._transform_parts, t_ns, position, quaternion)

    @staticmethod
    def _stamped_pose(message, parts, t_ns: int, position: list, orientation: list) -> bytes:
        """Fill and serialise a message of a google.protobuf.Timestamp, a foxglove.Vector3 and a
        foxglove.Quaternion (`parts`) from flat lists."""
        stamp, vector, quaternion = parts
        stamp.seconds, stamp.nanos = divmod(t_ns, NS_PER_S)
        vector.x, vector.y, vector.z = position
        quaternion.x, quaternion.y, quaternion.z, quaternion.w = orientation
        return message.SerializeToString()


# --- columns: a handover's ticks field by field ------------------------------------------------

@dataclass(frozen=True)
class Sparse:
    """The column of a field that some rows leave out (None)."""
    present: np.ndarray         # (n,) bool
    values: Any                 # the column of the present rows


def column(values: list) -> Any:
    """One field's values, a row each, as one object cheap to pickle: an array whose first axis is
    the row when all are there and of one shape, `Sparse` when some are None, None when all are,
    else the list itself (arrays of different shapes, such as support polygons)."""
    try:
        stacked = np.array(values)
    except ValueError:          # arrays of different shapes, or arrays and None
        stacked = None
    if stacked is not None and stacked.dtype != object:
        return stacked
    present = [value is not None for value in values]
    if all(present):
        return list(values)
    return Sparse(np.array(present), column([v for v in values if v is not None])) if any(present) else None


def column_rows(column: Any, count: int) -> list:
    """A column's `count` values, arrays as flat row-major lists (what `MessageEncoder` fills
    repeated fields from), absent ones as None."""
    if column is None:
        return [None] * count
    if isinstance(column, Sparse):
        present = iter(column_rows(column.values, int(column.present.sum())))
        return [next(present) if here else None for here in column.present.tolist()]
    if isinstance(column, list):
        return [_flat(value) if isinstance(value, (np.ndarray, list, tuple)) else value for value in column]
    if column.ndim == 1:
        return column.tolist()
    return column.reshape(len(column), math.prod(column.shape[1:])).tolist()


class Columns(NamedTuple):
    """Messages of one kind field by field: `fields` maps a field name to its column."""
    count: int
    fields: dict[str, Any]

    @classmethod
    def of(cls, records: list, names: tuple[str, ...], **extra: Any) -> "Columns":
        """The columns of the attributes `names` of `records`, and `extra` columns given as such."""
        get = attrgetter(*names)
        rows = map(get, records) if len(names) > 1 else ((get(record),) for record in records)
        values = list(zip(*rows)) or [()] * len(names)
        return cls(len(records), {**dict(zip(names, map(column, map(list, values)))), **extra})

    def rows(self, name: str) -> list:
        return column_rows(self.fields[name], self.count)


class TickColumns(NamedTuple):
    """A handover's ticks as columns: what `McapRecorder` hands its writer (`Encoder.messages`)."""
    first_sequence: int             # the first sample's sequence number
    samples_per_tick: np.ndarray    # (ticks,) int
    sample_kinds: np.ndarray        # (samples,) int, each sample's index in sample_types, in tick order
    sample_types: tuple[type, ...]
    samples: tuple[Columns, ...]    # the samples of each type: the dataclass's fields
    estimates_per_tick: np.ndarray  # (ticks,) int
    estimates: Columns              # the fields of `Estimate`
    truth: Columns                  # every tick: t, body_position, quaternion, foot_positions, foot_contact
    heavy: np.ndarray               # (ticks,) bool: the ticks whose heavy truth and command are recorded
    state: Columns                  # the heavy ticks' `Truth`, and their quaternion
    contacts: Columns               # t and the fields of `FootContacts`
    support: Columns                # the fields of the Support message
    commands: Columns               # the fields of `Command`

    @classmethod
    def of(cls, ticks: list[Tick], heavy: list[bool], first_sequence: int) -> "TickColumns":
        samples = [sample for tick in ticks for sample in tick.samples]
        sample_types = tuple(dict.fromkeys(map(type, samples)))
        kind_of = {kind: index for index, kind in enumerate(sample_types)}
        kinds = [kind_of[type(sample)] for sample in samples]
        estimates = [estimate for tick in ticks for estimate in tick.estimates]
        heavy_ticks = [tick for tick, is_heavy in zip(ticks, heavy) if is_heavy]
        state = Columns.of([tick.truth for tick in heavy_ticks], Truth._fields,
                           quaternion=column([tick.truth_quaternion for tick in heavy_ticks]))
        t = state.fields["t"]
        return cls(
            first_sequence=first_sequence,
            samples_per_tick=np.array([len(tick.samples) for tick in ticks], dtype=int),
            sample_kinds=np.array(kinds, dtype=int), sample_types=sample_types,
            samples=tuple(Columns.of([s for s in samples if type(s) is kind], _field_names(kind))
                          for kind in sample_types),
            estimates_per_tick=np.array([len(tick.estimates) for tick in ticks], dtype=int),
            estimates=Columns.of(estimates, _ESTIMATE_FIELDS),
            truth=Columns.of([tick.truth for tick in ticks], ("t", "body_position", "foot_positions", "foot_contact"),
                             quaternion=column([tick.truth_quaternion for tick in ticks])),
            heavy=np.array(heavy, dtype=bool), state=state,
            contacts=Columns.of([tick.contacts for tick in heavy_ticks], FootContacts._fields, t=t),
            support=Columns(len(heavy_ticks), {
                "t": t, "polygon": column([tick.support_polygon for tick in heavy_ticks]),
                "com_projection": column([tick.truth.com_position[:2] for tick in heavy_ticks]),
                "stability_margin": column([float(tick.stability_margin) for tick in heavy_ticks])}),
            commands=Columns.of([tick.command for tick in heavy_ticks], Command._fields))


def _field_names(dataclass_type: type) -> tuple[str, ...]:
    return tuple(field.name for field in fields(dataclass_type))


_ESTIMATE_FIELDS = _field_names(Estimate)


def robot_description_message(urdf: str) -> bytes:
    """The /robot_description message: the URDF at t = 0."""
    return schemas.RobotDescriptionMsg(t=0.0, data=urdf).SerializeToString()


def terrain_message(centers: np.ndarray, half_extents: np.ndarray, rotations: np.ndarray, name: str) -> bytes:
    """The terrain's boxes as one Foxglove scene entity of cubes (world frame)."""
    update = SceneUpdate()
    entity = update.entities.add(frame_id=WORLD_FRAME, id=f"terrain/{name}", frame_locked=True)
    quaternions = Rotation.from_matrix(rotations).as_quat() if len(rotations) else np.zeros((0, 4))
    for center, half, quaternion in zip(centers, half_extents, quaternions):
        cube: CubePrimitive = entity.cubes.add()
        cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = center.tolist()
        o = cube.pose.orientation
        o.x, o.y, o.z, o.w = quaternion.tolist()
        cube.size.x, cube.size.y, cube.size.z = (2 * half).tolist()
        cube.color.r, cube.color.g, cube.color.b, cube.color.a = 0.55, 0.5, 0.42, 1.0
    return update.SerializeToString()


# --- decoding -------------------------------------------------------------------------------

def _array(values, shape: tuple[int, ...] | None = None) -> np.ndarray:
    array = np.array(values, dtype=float)
    return array if shape is None else array.reshape(shape)


def _optional_matrix(values) -> np.ndarray | None:
    return _array(values, (3, 3)) if len(values) else None


def decode_sample(topic: str, data: bytes) -> Sample:
    if topic == schemas.IMU.name:
        m = schemas.ImuSampleMsg.FromString(data)
        return ImuSample(m.t, _array(m.accel), _array(m.gyro))
    if topic == schemas.ENCODERS.name:
        m = schemas.EncoderSampleMsg.FromString(data)
        return EncoderSample(m.t, _array(m.positions))
    if topic == schemas.FEET.name:
        m = schemas.FootSampleMsg.FromString(data)
        return FootSample(m.t, _array(m.normal_forces), np.array(m.contact, dtype=bool))
    if topic == schemas.ACCEL_ARRAY.name:
        m = schemas.AccelSampleMsg.FromString(data)
        return AccelSample(m.t, m.index, _array(m.accel))
    raise ValueError(f"{topic} is not a sensor topic")


def decode_plugin_sample(sample_class: type, data: bytes) -> Sample:
    """A sensor plugin's sample from its message (`schemas.sample_topic`); arrays come back flat,
    as float64."""
    message_class = schemas.sample_topic(sample_class).message_class
    message = message_class.FromString(data)
    return sample_class(**{name: _array(getattr(message, name)) if repeated else getattr(message, name)
                           for name, repeated in repeated_fields(message_class).items()})


def decode_estimate(data: bytes) -> Estimate:
    m = schemas.EstimateMsg.FromString(data)
    return Estimate(
        t=m.t, quaternion=_array(m.quaternion), roll=m.roll, pitch=m.pitch, yaw=m.yaw,
        attitude_cov=_optional_matrix(m.attitude_cov),
        gyro_bias=_array(m.gyro_bias) if len(m.gyro_bias) else None,
        gyro_bias_cov=_optional_matrix(m.gyro_bias_cov),
        terrain_roll=m.terrain_roll if m.HasField("terrain_roll") else None,
        terrain_pitch=m.terrain_pitch if m.HasField("terrain_pitch") else None,
        body_height=m.body_height if m.HasField("body_height") else None,
        terrain_cov=_optional_matrix(m.terrain_cov),
        position=_array(m.position) if len(m.position) else None,
        velocity=_array(m.velocity) if len(m.velocity) else None,
        position_cov=_optional_matrix(m.position_cov), velocity_cov=_optional_matrix(m.velocity_cov))


def decode_pose(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), quaternion x, y, z, w (4,)) of a PoseInFrame."""
    pose = PoseInFrame.FromString(data).pose
    p, o = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.x, o.y, o.z, o.w])


def decode_feet(data: bytes) -> tuple[float, np.ndarray, np.ndarray]:
    """(t, foot centres (6, 3), contact flags (6,)) of a FeetTruth message."""
    m = schemas.FeetTruthMsg.FromString(data)
    return m.t, _array(m.foot_positions, (-1, 3)), np.array(m.foot_contact, dtype=bool)


def decode_truth_state(data: bytes) -> Truth:
    m = schemas.TruthStateMsg.FromString(data)
    return Truth(
        t=m.t, body_position=_array(m.body_position), body_rotation=_array(m.body_rotation, (3, 3)),
        body_linear_velocity=_array(m.body_linear_velocity), body_angular_velocity=_array(m.body_angular_velocity),
        body_linear_acceleration=_array(m.body_linear_acceleration),
        body_angular_acceleration=_array(m.body_angular_acceleration),
        joint_positions=_array(m.joint_positions), joint_velocities=_array(m.joint_velocities),
        foot_positions=_array(m.foot_positions, (-1, 3)), foot_forces=_array(m.foot_forces, (-1, 3)),
        foot_normal_forces=_array(m.foot_normal_forces), foot_contact=np.array(m.foot_contact, dtype=bool),
        com_position=_array(m.com_position))


def decode_contacts(data: bytes) -> tuple[float, FootContacts]:
    m = schemas.ContactsMsg.FromString(data)
    return m.t, FootContacts(forces=_array(m.forces, (-1, 3)), normal_forces=_array(m.normal_forces),
                             normals=_array(m.normals, (-1, 3)), points=_array(m.points, (-1, 3)),
                             in_contact=np.array(m.in_contact, dtype=bool))


def decode_support(data: bytes) -> SupportSample:
    m = schemas.SupportMsg.FromString(data)
    return SupportSample(m.t, _array(m.polygon, (-1, 2)), _array(m.com_projection), m.stability_margin)


def decode_command(data: bytes) -> Command:
    m = schemas.CommandMsg.FromString(data)
    return Command(t=m.t, phase=_array(m.phase), swinging=np.array(m.swinging, dtype=bool),
                   foot_targets=_array(m.foot_targets, (-1, 3)), joint_targets=_array(m.joint_targets),
                   body_twist=_array(m.body_twist))


def decode_terrain(data: bytes) -> TerrainBoxes:
    cubes = [cube for entity in SceneUpdate.FromString(data).entities for cube in entity.cubes]
    centers = np.array([[c.pose.position.x, c.pose.position.y, c.pose.position.z] for c in cubes]).reshape(-1, 3)
    sizes = np.array([[c.size.x, c.size.y, c.size.z] for c in cubes]).reshape(-1, 3)
    quaternions = np.array([[c.pose.orientation.x, c.pose.orientation.y, c.pose.orientation.z,
                             c.pose.orientation.w] for c in cubes]).reshape(-1, 4)
    return TerrainBoxes(centers, sizes, quaternions)
