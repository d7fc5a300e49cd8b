"""Conversion between the testbed's objects and the dataset's protobuf messages, both ways.

Encoding is lossless: every float is written as a float64, so decoding gives back bit-identical
arrays (NaN payloads included). `Encoder` writes the wire format directly (`datasets.wire`), the
same bytes as protobuf's SerializeToString at a fraction of the cost.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from operator import attrgetter

import numpy as np
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from scipy.spatial.transform import Rotation

from datasets import schemas, wire
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


def to_ns_many(times: Sequence[float]) -> list[int]:
    """`to_ns` of each time, in one numpy pass (the same product, rounded half to even like round)."""
    return np.rint(np.asarray(times, dtype=float) * NS_PER_S).astype(np.int64).tolist()


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


def _field_key(message_class: type, name: str, wire_type: int) -> bytes:
    return wire.key(message_class.DESCRIPTOR.fields_by_name[name].number, wire_type)


# Foxglove's messages, written with datasets.wire like the `hexapod` ones (see there why).
_TIMESTAMP = _field_key(PoseInFrame, "timestamp", wire.LENGTH_DELIMITED)
_SECONDS, _NANOS = wire.key(1, wire.VARINT), wire.key(2, wire.VARINT)      # google.protobuf.Timestamp
_POSE_FRAME = wire.string(_field_key(PoseInFrame, "frame_id", wire.LENGTH_DELIMITED), WORLD_FRAME)
_POSE = _field_key(PoseInFrame, "pose", wire.LENGTH_DELIMITED)
_POSITION, _ORIENTATION = wire.key(1, wire.LENGTH_DELIMITED), wire.key(2, wire.LENGTH_DELIMITED)   # foxglove.Pose
_TRANSFORM_FRAMES = (wire.string(_field_key(FrameTransform, "parent_frame_id", wire.LENGTH_DELIMITED), WORLD_FRAME)
                     + wire.string(_field_key(FrameTransform, "child_frame_id", wire.LENGTH_DELIMITED), BODY_FRAME))
_TRANSLATION = _field_key(FrameTransform, "translation", wire.LENGTH_DELIMITED)
_ROTATION = _field_key(FrameTransform, "rotation", wire.LENGTH_DELIMITED)
# foxglove.Vector3 (x, y, z) and foxglove.Quaternion (x, y, z, w): doubles numbered 1 to 4.
_X, _Y, _Z, _W = (number << 3 | wire.FIXED64 for number in (1, 2, 3, 4))
_VECTOR3, _QUATERNION = struct.Struct("<BdBdBd").pack, struct.Struct("<BdBdBdBd").pack
# The Contacts message: t, then the FootContacts arrays of its other fields' names.
_CONTACT_ARRAYS = attrgetter(*(name for name, _, _ in schemas.MESSAGES["Contacts"][1:]))


def _timestamp(t_ns: int) -> bytes:
    seconds, nanos = divmod(t_ns, NS_PER_S)
    return wire.length_delimited(_TIMESTAMP, wire.unsigned(_SECONDS, seconds) + _nanos(nanos))


@lru_cache(maxsize=4096)
def _nanos(nanos: int) -> bytes:
    """The Timestamp's nanos field: recurring values (whole milliseconds at the physics rate), and
    its varint of 3 to 5 bytes costs a Python loop."""
    return wire.unsigned(_NANOS, nanos)


# A foxglove.Vector3 and a foxglove.Quaternion, each as a length-delimited field, with every
# component written: one structured-array row, the fields' keys and lengths filled in.
_COMPONENT = np.dtype([("key", np.uint8), ("value", "<f8")])
_PAIR = np.dtype([("first", np.uint8, (2,)), ("vector", _COMPONENT, (3,)), ("second", np.uint8, (2,)),
                  ("quaternion", _COMPONENT, (4,))])


def _vector_and_quaternion(first_key: bytes, vectors: np.ndarray, second_key: bytes,
                           quaternions: np.ndarray) -> list[bytes]:
    """Per row of `vectors` (N, 3) and `quaternions` (N, 4): the field `first_key` holding the
    foxglove.Vector3, then `second_key` holding the foxglove.Quaternion. Vectorised over the rows
    without a zero component (all fields written), one by one for the others."""
    rows = np.empty(len(vectors), _PAIR)
    rows["first"] = (first_key[0], 3 * _COMPONENT.itemsize)
    rows["vector"]["key"] = (_X, _Y, _Z)
    rows["vector"]["value"] = vectors
    rows["second"] = (second_key[0], 4 * _COMPONENT.itemsize)
    rows["quaternion"]["key"] = (_X, _Y, _Z, _W)
    rows["quaternion"]["value"] = quaternions
    data, size = rows.tobytes(), _PAIR.itemsize
    complete = (vectors != 0.0).all(axis=1) & (quaternions != 0.0).all(axis=1)
    return [data[index * size:(index + 1) * size] if whole else
            (wire.length_delimited(first_key, _vector3(vector))
             + wire.length_delimited(second_key, _quaternion(quaternion)))
            for index, (whole, vector, quaternion) in enumerate(zip(complete.tolist(), vectors, quaternions))]


def _vector3(values: np.ndarray) -> bytes:
    x, y, z = values.tolist()
    if x and y and z:       # none of them a zero of either sign: every field written, in one pack
        return _VECTOR3(_X, x, _Y, y, _Z, z)
    return _each_component((x, y, z))


def _quaternion(values: np.ndarray) -> bytes:
    x, y, z, w = values.tolist()
    if x and y and z and w:
        return _QUATERNION(_X, x, _Y, y, _Z, z, _W, w)
    return _each_component((x, y, z, w))


def _each_component(components: tuple[float, ...]) -> bytes:
    return b"".join([wire.double(wire.varint(field_key), value)
                     for field_key, value in zip((_X, _Y, _Z, _W), components)])


class Encoder:
    """Serialises objects into protobuf bytes (datasets.wire: protobuf's own bytes), one at a time
    or in batches (the plural methods, vectorised over the batch, in the batch's order)."""

    def __init__(self) -> None:
        layouts = {name: wire.Layout(fields) for name, fields in schemas.MESSAGES.items()}
        self._samples = {ImuSample: (schemas.IMU.name, layouts["ImuSample"]),
                         AccelSample: (schemas.ACCEL_ARRAY.name, layouts["AccelSample"]),
                         EncoderSample: (schemas.ENCODERS.name, layouts["EncoderSample"]),
                         FootSample: (schemas.FEET.name, layouts["FootSample"])}
        self._estimate, self._feet, self._state = layouts["Estimate"], layouts["FeetTruth"], layouts["TruthState"]
        self._contacts, self._support, self._command = layouts["Contacts"], layouts["Support"], layouts["Command"]

    def _sample_layout(self, sample: Sample) -> tuple[str, wire.Layout]:
        try:
            return self._samples[type(sample)]
        except KeyError:
            raise TypeError(f"cannot record a {type(sample).__name__}") from None

    def sample(self, sample: Sample) -> tuple[str, bytes]:
        """(topic name, message bytes) of one sensor sample."""
        topic, layout = self._sample_layout(sample)
        return topic, layout.encode_fields_of(sample)

    def samples(self, samples: Sequence[Sample]) -> list[tuple[str, bytes]]:
        by_type: dict[type, list[int]] = {}
        for index, sample in enumerate(samples):
            by_type.setdefault(type(sample), []).append(index)
        encoded: list = [None] * len(samples)
        for indices in by_type.values():
            topic, layout = self._sample_layout(samples[indices[0]])
            for index, data in zip(indices, layout.encode_fields_of_many([samples[index] for index in indices])):
                encoded[index] = (topic, data)
        return encoded

    def estimate(self, estimate: Estimate) -> bytes:
        return self._estimate.encode_fields_of(estimate)

    def estimates(self, estimates: Sequence[Estimate]) -> list[bytes]:
        return self._estimate.encode_fields_of_many(estimates)

    def pose(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        return self.poses([t_ns], [position], [quaternion])[0]

    def poses(self, times_ns: Sequence[int], positions: Sequence[np.ndarray],
              quaternions: Sequence[np.ndarray]) -> list[bytes]:
        bodies = _vector_and_quaternion(_POSITION, np.array(positions, dtype=float).reshape(-1, 3), _ORIENTATION,
                                        np.array(quaternions, dtype=float).reshape(-1, 4))
        return [_timestamp(t_ns) + _POSE_FRAME + wire.length_delimited(_POSE, body)
                for t_ns, body in zip(times_ns, bodies)]

    def feet(self, truth: Truth) -> bytes:
        return self._feet.encode_fields_of(truth)

    def feet_of(self, truths: Sequence[Truth]) -> list[bytes]:
        return self._feet.encode_fields_of_many(truths)

    def transform(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        return self.transforms([t_ns], [position], [quaternion])[0]

    def transforms(self, times_ns: Sequence[int], positions: Sequence[np.ndarray],
                   quaternions: Sequence[np.ndarray]) -> list[bytes]:
        parts = _vector_and_quaternion(_TRANSLATION, np.array(positions, dtype=float).reshape(-1, 3), _ROTATION,
                                       np.array(quaternions, dtype=float).reshape(-1, 4))
        return [_timestamp(t_ns) + _TRANSFORM_FRAMES + part for t_ns, part in zip(times_ns, parts)]

    def truth_state(self, truth: Truth) -> bytes:
        return self._state.encode_fields_of(truth)

    def truth_states(self, truths: Sequence[Truth]) -> list[bytes]:
        return self._state.encode_fields_of_many(truths)

    def contacts(self, t: float, contacts: FootContacts) -> bytes:
        return self._contacts.encode((t, *_CONTACT_ARRAYS(contacts)))

    def contacts_of(self, times: Sequence[float], contacts: Sequence[FootContacts]) -> list[bytes]:
        return self._contacts.encode_many([(t, *_CONTACT_ARRAYS(each)) for t, each in zip(times, contacts)])

    def support(self, t: float, polygon: np.ndarray, com_projection: np.ndarray, margin: float) -> bytes:
        return self._support.encode((t, polygon, com_projection, float(margin)))

    def command(self, command: Command) -> bytes:
        return self._command.encode_fields_of(command)

    def commands(self, commands: Sequence[Command]) -> list[bytes]:
        return self._command.encode_fields_of_many(commands)


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
