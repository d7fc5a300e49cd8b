"""Conversion between the testbed's objects and the dataset's protobuf messages, both ways.

Encoding is lossless: every float is written as a float64, so decoding gives back bit-identical
arrays (NaN payloads included). `Encoder` reuses one message object per type, which is about a
third cheaper than building a fresh one per tick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from scipy.spatial.transform import Rotation

from datasets import schemas
from estimators.base import Estimate
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample, Sample
from testbed.contact import FootContacts
from testbed.recording import Command
from testbed.truth import Truth

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


# TruthState's array fields, each flattened row-major (foot_contact is bool, the rest float64).
TRUTH_STATE_ARRAYS = ("body_position", "body_rotation", "body_linear_velocity", "body_angular_velocity",
                      "body_linear_acceleration", "body_angular_acceleration", "joint_positions", "joint_velocities",
                      "foot_positions", "foot_forces", "foot_normal_forces", "foot_contact", "com_position")


def _floats(values: np.ndarray) -> list[float]:
    return np.asarray(values, dtype=float).ravel().tolist()


def _set_timestamp(stamp, t_ns: int) -> None:
    stamp.seconds, stamp.nanos = divmod(t_ns, NS_PER_S)


class Encoder:
    """Serialises one object at a time into protobuf bytes."""

    def __init__(self) -> None:
        self._imu = schemas.ImuSampleMsg()
        self._accel = schemas.AccelSampleMsg()
        self._encoder = schemas.EncoderSampleMsg()
        self._foot = schemas.FootSampleMsg()
        self._estimate = schemas.EstimateMsg()
        self._feet = schemas.FeetTruthMsg()
        self._pose = PoseInFrame(frame_id=WORLD_FRAME)
        self._transform = FrameTransform(parent_frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME)
        self._state = schemas.TruthStateMsg()
        self._contacts = schemas.ContactsMsg()
        self._support = schemas.SupportMsg()
        self._command = schemas.CommandMsg()

    def sample(self, sample: Sample) -> tuple[str, bytes]:
        """(topic name, message bytes) of one sensor sample."""
        if isinstance(sample, ImuSample):
            m = self._imu
            m.t = sample.t
            m.accel[:] = sample.accel.tolist()
            m.gyro[:] = sample.gyro.tolist()
            return schemas.IMU.name, m.SerializeToString()
        if isinstance(sample, EncoderSample):
            m = self._encoder
            m.t = sample.t
            m.positions[:] = sample.positions.tolist()
            return schemas.ENCODERS.name, m.SerializeToString()
        if isinstance(sample, FootSample):
            m = self._foot
            m.t = sample.t
            m.normal_forces[:] = sample.normal_forces.tolist()
            m.contact[:] = sample.contact.tolist()
            return schemas.FEET.name, m.SerializeToString()
        if isinstance(sample, AccelSample):
            m = self._accel
            m.t, m.index = sample.t, sample.index
            m.accel[:] = sample.accel.tolist()
            return schemas.ACCEL_ARRAY.name, m.SerializeToString()
        raise TypeError(f"cannot record a {type(sample).__name__}")

    def estimate(self, estimate: Estimate) -> bytes:
        m = self._estimate
        m.t, m.roll, m.pitch, m.yaw = estimate.t, estimate.roll, estimate.pitch, estimate.yaw
        m.quaternion[:] = estimate.quaternion.tolist()
        for name in ("attitude_cov", "gyro_bias", "gyro_bias_cov", "terrain_cov"):
            value = getattr(estimate, name)
            getattr(m, name)[:] = [] if value is None else value.ravel().tolist()
        for name in ("terrain_roll", "terrain_pitch", "body_height"):
            value = getattr(estimate, name)
            if value is None:
                m.ClearField(name)
            else:
                setattr(m, name, value)
        return m.SerializeToString()

    def pose(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        m = self._pose
        _set_timestamp(m.timestamp, t_ns)
        p, o = m.pose.position, m.pose.orientation
        p.x, p.y, p.z = position.tolist()
        o.x, o.y, o.z, o.w = quaternion.tolist()
        return m.SerializeToString()

    def feet(self, truth: Truth) -> bytes:
        m = self._feet
        m.t = truth.t
        m.foot_positions[:] = truth.foot_positions.ravel().tolist()
        m.foot_contact[:] = truth.foot_contact.tolist()
        return m.SerializeToString()

    def transform(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> bytes:
        m = self._transform
        _set_timestamp(m.timestamp, t_ns)
        p, o = m.translation, m.rotation
        p.x, p.y, p.z = position.tolist()
        o.x, o.y, o.z, o.w = quaternion.tolist()
        return m.SerializeToString()

    def truth_state(self, truth: Truth) -> bytes:
        m = self._state
        m.t = truth.t
        for name in TRUTH_STATE_ARRAYS:
            getattr(m, name)[:] = getattr(truth, name).ravel().tolist()
        return m.SerializeToString()

    def contacts(self, t: float, contacts: FootContacts) -> bytes:
        m = self._contacts
        m.t = t
        m.points[:] = contacts.points.ravel().tolist()
        m.normals[:] = contacts.normals.ravel().tolist()
        m.forces[:] = contacts.forces.ravel().tolist()
        m.normal_forces[:] = contacts.normal_forces.tolist()
        m.in_contact[:] = contacts.in_contact.tolist()
        return m.SerializeToString()

    def support(self, t: float, polygon: np.ndarray, com_projection: np.ndarray, margin: float) -> bytes:
        m = self._support
        m.t, m.stability_margin = t, float(margin)
        m.polygon[:] = _floats(polygon)
        m.com_projection[:] = _floats(com_projection)
        return m.SerializeToString()

    def command(self, command: Command) -> bytes:
        m = self._command
        m.t = command.t
        m.phase[:] = _floats(command.phase)
        m.swinging[:] = np.asarray(command.swinging, bool).tolist()
        m.foot_targets[:] = _floats(command.foot_targets)
        m.joint_targets[:] = _floats(command.joint_targets)
        m.body_twist[:] = _floats(command.body_twist)
        return m.SerializeToString()


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
