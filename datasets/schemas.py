"""Protobuf schemas of the dataset's own messages, and the topic table.

Poses and transforms use Foxglove's schemas (foxglove.PoseInFrame, foxglove.FrameTransforms,
foxglove.SceneUpdate) so that Foxglove and Rerun draw them. Everything else is a message of the
`hexapod` package below, built at import time from descriptors (no generated code to keep in
sync); each MCAP file carries the full FileDescriptorSet of its schemas, so any protobuf reader
can decode a file without this module.

Every `hexapod` message starts with `double t`, the simulation time in seconds exactly as the
simulation produced it (the MCAP log time is the same instant rounded to nanoseconds). Vectors
and matrices are packed repeated doubles, row-major. A proto3 `optional` field is absent where the
estimator gives no value; an empty repeated field likewise.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from functools import cache

import numpy as np

from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass

PACKAGE = "hexapod"
FORMAT_VERSION = "1"

_TYPES = {"double": descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
          "int64": descriptor_pb2.FieldDescriptorProto.TYPE_INT64,
          "bool": descriptor_pb2.FieldDescriptorProto.TYPE_BOOL,
          "uint32": descriptor_pb2.FieldDescriptorProto.TYPE_UINT32,
          "string": descriptor_pb2.FieldDescriptorProto.TYPE_STRING,
          "bytes": descriptor_pb2.FieldDescriptorProto.TYPE_BYTES}

# message name -> fields (name, type, kind); kind: "one" (singular), "many" (repeated), "maybe"
# (proto3 optional). Field numbers follow the order; never reorder, only append.
MESSAGES: dict[str, list[tuple[str, str, str]]] = {
    "ImuSample": [("t", "double", "one"), ("accel", "double", "many"), ("gyro", "double", "many")],
    "AccelSample": [("t", "double", "one"), ("index", "uint32", "one"), ("accel", "double", "many")],
    "EncoderSample": [("t", "double", "one"), ("positions", "double", "many")],
    "FootSample": [("t", "double", "one"), ("normal_forces", "double", "many"), ("contact", "bool", "many")],
    "Estimate": [("t", "double", "one"), ("quaternion", "double", "many"), ("roll", "double", "one"),
                 ("pitch", "double", "one"), ("yaw", "double", "one"), ("attitude_cov", "double", "many"),
                 ("gyro_bias", "double", "many"), ("gyro_bias_cov", "double", "many"),
                 ("terrain_roll", "double", "maybe"), ("terrain_pitch", "double", "maybe"),
                 ("body_height", "double", "maybe"), ("terrain_cov", "double", "many"),
                 ("position", "double", "many"), ("velocity", "double", "many"), ("position_cov", "double", "many"),
                 ("velocity_cov", "double", "many")],
    "FeetTruth": [("t", "double", "one"), ("foot_positions", "double", "many"), ("foot_contact", "bool", "many")],
    "TruthState": [("t", "double", "one"), ("body_position", "double", "many"),
                   ("body_rotation", "double", "many"), ("body_linear_velocity", "double", "many"),
                   ("body_angular_velocity", "double", "many"), ("body_linear_acceleration", "double", "many"),
                   ("body_angular_acceleration", "double", "many"), ("joint_positions", "double", "many"),
                   ("joint_velocities", "double", "many"), ("foot_positions", "double", "many"),
                   ("foot_forces", "double", "many"), ("foot_normal_forces", "double", "many"),
                   ("foot_contact", "bool", "many"), ("com_position", "double", "many")],
    "Contacts": [("t", "double", "one"), ("points", "double", "many"), ("normals", "double", "many"),
                 ("forces", "double", "many"), ("normal_forces", "double", "many"), ("in_contact", "bool", "many")],
    "Support": [("t", "double", "one"), ("polygon", "double", "many"), ("com_projection", "double", "many"),
                ("stability_margin", "double", "one")],
    "Command": [("t", "double", "one"), ("phase", "double", "many"), ("swinging", "bool", "many"),
                ("foot_targets", "double", "many"), ("joint_targets", "double", "many"),
                ("body_twist", "double", "many")],
    # `data`, the URDF text, as in ROS's std_msgs/String: what Foxglove's 3D panel reads from /robot_description.
    "RobotDescription": [("t", "double", "one"), ("data", "string", "one")],
}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    return _file_proto(f"{PACKAGE}/dataset.proto", PACKAGE, MESSAGES)


def _file_proto(name: str, package: str, messages: dict[str, list[tuple[str, str, str]]]):
    proto = descriptor_pb2.FileDescriptorProto(name=name, package=package, syntax="proto3")
    for message_name, fields in messages.items():
        message = proto.message_type.add(name=message_name)
        for number, (name, type_name, kind) in enumerate(fields, start=1):
            field = message.field.add(name=name, number=number, type=_TYPES[type_name], json_name=name,
                                      label=descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED if kind == "many"
                                      else descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL)
            if kind == "maybe":
                # proto3 `optional`: a synthetic one-field oneof gives the field presence.
                field.proto3_optional = True
                field.oneof_index = len(message.oneof_decl)
                message.oneof_decl.add(name=f"_{name}")
    return proto


def _message_classes(proto: descriptor_pb2.FileDescriptorProto) -> dict[str, type]:
    file = descriptor_pool.DescriptorPool().Add(proto)
    return {name: GetMessageClass(file.message_types_by_name[name]) for name in MESSAGES}


def _packed_views() -> dict[str, type]:
    """Each message with its repeated (packed) fields declared `bytes` under the same numbers: a
    packed field's wire form is one length-delimited run of its values, exactly as a `bytes`
    field's, so protobuf parses a recorded message with these classes and hands each array over
    as its raw little-endian bytes (see `datasets.message_columns`)."""
    views = {name: [(field, "bytes" if kind == "many" else type_name, "one" if kind == "many" else kind)
                    for field, type_name, kind in fields] for name, fields in MESSAGES.items()}
    return _message_classes(_file_proto(f"{PACKAGE}/packed_view.proto", f"{PACKAGE}.packed_view", views))


CLASSES = _message_classes(_file_descriptor())
PACKED_VIEWS = _packed_views()
ImuSampleMsg = CLASSES["ImuSample"]
AccelSampleMsg = CLASSES["AccelSample"]
EncoderSampleMsg = CLASSES["EncoderSample"]
FootSampleMsg = CLASSES["FootSample"]
EstimateMsg = CLASSES["Estimate"]
FeetTruthMsg = CLASSES["FeetTruth"]
TruthStateMsg = CLASSES["TruthState"]
ContactsMsg = CLASSES["Contacts"]
SupportMsg = CLASSES["Support"]
CommandMsg = CLASSES["Command"]
RobotDescriptionMsg = CLASSES["RobotDescription"]


@dataclass(frozen=True)
class Topic:
    name: str
    message_class: type
    description: str
    sample_class: str | None = None     # MODULE:CLASS of a sensor plugin's sample type (channel metadata)


TRUTH_POSE = Topic("/truth/pose", PoseInFrame, "body pose in the world frame at every physics step")
TF = Topic("/tf", FrameTransforms, "world -> body and every joint's parent -> child link transform, at the truth rate")
TERRAIN = Topic("/terrain", SceneUpdate, "the terrain's boxes, once at t = 0")
TRUTH_FEET = Topic("/truth/feet", FeetTruthMsg, "foot centres and contact flags at every physics step")
TRUTH_STATE = Topic("/truth/state", TruthStateMsg, "body twist and accelerations, joints, feet, centre of mass")
TRUTH_CONTACTS = Topic("/truth/contacts", ContactsMsg, "contact points, normals and forces")
TRUTH_SUPPORT = Topic("/truth/support", SupportMsg, "support polygon, centre-of-mass projection, stability margin")
IMU = Topic("/sensors/imu", ImuSampleMsg, "IMU samples")
ACCEL_ARRAY = Topic("/sensors/accel_array", AccelSampleMsg, "accelerometer-array samples")
ENCODERS = Topic("/sensors/encoders", EncoderSampleMsg, "joint-encoder samples")
FEET = Topic("/sensors/feet", FootSampleMsg, "foot force-sensor samples")
ESTIMATE = Topic("/estimate", EstimateMsg, "estimator output with covariances")
COMMAND = Topic("/command", CommandMsg, "gait phase, foot targets, joint commands, commanded twist")
ROBOT_DESCRIPTION = Topic("/robot_description", RobotDescriptionMsg, "the robot's URDF, once at t = 0")

TOPICS = (TRUTH_POSE, TRUTH_FEET, TF, TERRAIN, TRUTH_STATE, TRUTH_CONTACTS, TRUTH_SUPPORT, IMU, ACCEL_ARRAY, ENCODERS, FEET,
          ESTIMATE, COMMAND, ROBOT_DESCRIPTION)
SENSOR_TOPICS = (IMU.name, ACCEL_ARRAY.name, ENCODERS.name, FEET.name)
SENSOR_PREFIX = "/sensors/"
SAMPLES_PACKAGE = f"{PACKAGE}.samples"

# A sample dataclass's field types and the protobuf fields that record them.
_SAMPLE_FIELDS = {float: ("double", "one"), int: ("int64", "one"), bool: ("bool", "one"),
                  np.ndarray: ("double", "many"), tuple: ("double", "many")}


@cache
def sample_topic(sample_class: type) -> Topic:
    """The topic of a sensor plugin's sample type: `/sensors/<module>.<Class>`, with a message of
    the dataclass's fields (float -> double, int -> int64, bool -> bool, arrays and tuples ->
    repeated double, row-major) in the package `hexapod.samples.<module>`."""
    if not dataclasses.is_dataclass(sample_class):
        raise TypeError(f"cannot record a {sample_class.__name__}: sensor samples are dataclasses")
    hints = typing.get_type_hints(sample_class)
    fields = []
    for field in dataclasses.fields(sample_class):
        hint = typing.get_origin(hints[field.name]) or hints[field.name]
        if hint not in _SAMPLE_FIELDS:
            raise TypeError(f"cannot record {sample_class.__name__}.{field.name} of type {hints[field.name]}")
        fields.append((field.name, *_SAMPLE_FIELDS[hint]))
    package = f"{SAMPLES_PACKAGE}.{sample_class.__module__}"
    proto = _file_proto(f"{PACKAGE}/samples/{sample_class.__module__}.{sample_class.__qualname__}.proto", package,
                        {sample_class.__qualname__: fields})
    message_class = GetMessageClass(descriptor_pool.DescriptorPool().Add(proto).message_types_by_name[
        sample_class.__qualname__])
    spec = f"{sample_class.__module__}:{sample_class.__qualname__}"
    return Topic(f"{SENSOR_PREFIX}{sample_class.__module__}.{sample_class.__qualname__}", message_class,
                 f"samples of {spec}", spec)
