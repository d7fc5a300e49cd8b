"""Conversion between the testbed's objects and the dataset's protobuf messages, both ways.

Encoding goes through the message classes (`datasets.schemas`, Foxglove's) and protobuf's
`SerializeToString`; decoding through `FromString`. Every float is a float64, so decoding gives
back bit-identical arrays (NaN payloads included).
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pb2
from scipy.spatial.transform import Rotation

from datasets import schemas
from estimators.base import Estimate
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from testbed.world.contact import FootContacts
from testbed.control.command import Command
from testbed.model.truth import Truth

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
    `hexapod` messages) from their field values, in the order the descriptor lists the fields:
    `encode` takes the values in that order, `encode_fields_of` reads the attributes named as the
    fields. Arrays of any shape go to repeated fields row-major; None leaves a field absent (an
    unset proto3 `optional`, an empty repeated field).

    One message object is filled again for each call, its repeated fields' containers looked up
    once: cheaper than building a new message each time."""

    def __init__(self, message_class: type):
        message = self._message = message_class()
        repeated = repeated_fields(message_class)
        # (name, the repeated field's container or None for a singular field)
        self._fields = [(name, getattr(message, name) if repeated[name] else None) for name in repeated]
        getter = attrgetter(*(name for name, _ in self._fields))
        self._values_of = getter if len(self._fields) > 1 else lambda item: (getter(item),)

    def encode_fields_of(self, item: Any) -> bytes:
        return self.encode(self._values_of(item))

    def encode(self, values: Any) -> bytes:
        message = self._message
        for (name, repeated), value in zip(self._fields, values):
            if repeated is not None:
                repeated[:] = () if value is None else _flat(value)
            elif value is None:
                message.ClearField(name)
            else:
                setattr(message, name, value)
        return message.SerializeToString()


# The Contacts message: t, then the FootContacts arrays of its other fields' names.
_CONTACT_ARRAYS = attrgetter(*(name for name, _, _ in schemas.MESSAGES["Contacts"][1:]))


class Encoder:
    """Serialises the testbed's objects into the dataset's messages, one at a time."""

    def __init__(self) -> None:
        encoders = {name: MessageEncoder(message_class) for name, message_class in schemas.CLASSES.items()}
        self._samples = {ImuSample: (schemas.IMU.name, encoders["ImuSample"]),
                         AccelSample: (schemas.ACCEL_ARRAY.name, encoders["AccelSample"]),
                         EncoderSample: (schemas.ENCODERS.name, encoders["EncoderSample"]),
                         FootSample: (schemas.FEET.name, encoders["FootSample"])}
        self._estimate, self._feet, self._state = encoders["Estimate"], encoders["FeetTruth"], encoders["TruthState"]
        self._contacts, self._support, self._command = encoders["Contacts"], encoders["Support"], encoders["Command"]
        self._pose = PoseInFrame(frame_id=WORLD_FRAME)
        self._pose_parts = (self._pose.timestamp, self._pose.pose.position, self._pose.pose.orientation)
        self._transform = FrameTransform(parent_frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME)
        self._transform_parts = (self._transform.timestamp, self._transform.translation, self._transform.rotation)

    def sample(self, sample: Sample) -> tuple[str, bytes]:
        """(topic name, message bytes) of one sensor sample; a sensor plugin's sample type gets
        its own topic (`schemas.sample_topic`)."""
        kind = type(sample)
        if kind not in self._samples:
            topic = schemas.sample_topic(kind)
            self._samples[kind] = (topic.name, MessageEncoder(topic.message_class))
        topic, encoder = self._samples[kind]
        return topic, encoder.encode_fields_of(sample)

    def estimate(self, estimate: Estimate) -> bytes:
        return self._estimate.encode_fields_of(estimate)

    def pose(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        _set_stamped_pose(self._pose_parts, t_ns, position, quaternion)
        return self._pose.SerializeToString()

    def feet(self, truth: Truth) -> bytes:
        return self._feet.encode_fields_of(truth)

    def transform(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        _set_stamped_pose(self._transform_parts, t_ns, position, quaternion)
        return self._transform.SerializeToString()

    def truth_state(self, truth: Truth) -> bytes:
        return self._state.encode_fields_of(truth)

    def contacts(self, t: float, contacts: FootContacts) -> bytes:
        return self._contacts.encode((t, *_CONTACT_ARRAYS(contacts)))

    def support(self, t: float, polygon: np.ndarray, com_projection: np.ndarray, margin: float) -> bytes:
        return self._support.encode((t, polygon, com_projection, float(margin)))

    def command(self, command: Command) -> bytes:
        return self._command.encode_fields_of(command)


def _set_stamped_pose(parts, t_ns: int, position: np.ndarray, orientation: np.ndarray) -> None:
    """Fill a google.protobuf.Timestamp, a foxglove.Vector3 and a foxglove.Quaternion."""
    stamp, vector, quaternion = parts
    stamp.seconds, stamp.nanos = divmod(t_ns, NS_PER_S)
    vector.x, vector.y, vector.z = _flat(position)
    quaternion.x, quaternion.y, quaternion.z, quaternion.w = _flat(orientation)


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
        terrain_cov=_optional_matrix(m.terrain_cov))


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
