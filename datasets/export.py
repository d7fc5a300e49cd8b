"""A recorded run in other tools' formats (`testbed export`): ROS 2 MCAP, TUM trajectories, CSV tables.

Every format reads the run through `datasets.dataset.Dataset.table`, one table per topic.

- `ros2`: an MCAP file of ROS 2 messages (`ros2msg` schemas, CDR, written by mcap-ros2-support's
  writer), stamped with the simulation time. Topics (docs/dataset.md, "Export"):
  `/imu` sensor_msgs/msg/Imu (frame `imu`: the IMU's samples in its own axes; its mounting on the
  body as the static transform `body` -> `imu` on `/tf_static`), `/joint_states`
  sensor_msgs/msg/JointState (the encoders), `/truth/joint_states` (the true joint angles and
  rates), `/tf` tf2_msgs/msg/TFMessage (every link's frame, from the native `/tf`),
  `/truth/pose` and `/estimate/pose` geometry_msgs/msg/PoseStamped. `/estimate/pose` has the
  estimated orientation and the estimated body position of a full-state estimator (`ekf`, `ukf`:
  in the start frame, origin at the body's start position, x along its start heading); an
  attitude-only estimator gives no position, and then the pose holds the estimated height above
  the support plane on z (0 when the estimator gives none) and 0 on x, y.
- `tum`: `truth.tum` and `estimate.tum`, one pose per line, `t x y z qx qy qz qw` (the TUM RGB-D
  format evo reads); the estimate's position as in `/estimate/pose` (start frame: compare with
  evo's `--align_origin`).
- `csv`: one `<topic>.csv` per time-series topic (slashes as underscores), the columns of
  `Dataset.table`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas
from mcap_ros2.writer import Writer as Ros2Writer

from datasets import schemas
from datasets.dataset import SUFFIXES, Dataset
from datasets.links import LinkTree
from testbed.model import spatial
from testbed.model.robot import joint_names

FORMATS = ("ros2", "tum", "csv")
NS_PER_S = 1_000_000_000
WORLD_FRAME, BODY_FRAME, IMU_FRAME = "world", "body", "imu"
NOT_TIME_SERIES = (schemas.TERRAIN.name,)
TRANSLATION_X = "_translation_x"

# ROS 2 message definitions (ros2/common_interfaces, comments and defaults left out), each with
# the definitions it uses, in the concatenated form of MCAP's ros2msg schema encoding.
_DEFINITIONS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "sensor_msgs/Imu": ("std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
                        "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
                        "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
                        "float64[9] linear_acceleration_covariance"),
    "sensor_msgs/JointState": ("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
                               "float64[] effort"),
}
_USES = {
    "std_msgs/Header": ("builtin_interfaces/Time",),
    "geometry_msgs/Pose": ("geometry_msgs/Point", "geometry_msgs/Quaternion"),
    "geometry_msgs/PoseStamped": ("std_msgs/Header", "geometry_msgs/Pose"),
    "geometry_msgs/Transform": ("geometry_msgs/Vector3", "geometry_msgs/Quaternion"),
    "geometry_msgs/TransformStamped": ("std_msgs/Header", "geometry_msgs/Transform"),
    "tf2_msgs/TFMessage": ("geometry_msgs/TransformStamped",),
    "sensor_msgs/Imu": ("std_msgs/Header", "geometry_msgs/Quaternion", "geometry_msgs/Vector3"),
    "sensor_msgs/JointState": ("std_msgs/Header",),
}
SEPARATOR = "=" * 80
NO_ORIENTATION = [-1.0] + [0.0] * 8         # sensor_msgs/Imu: the IMU gives no orientation
UNKNOWN_COVARIANCE = [0.0] * 9


def export(dataset: Dataset, format: str, out: Path) -> list[Path]:
    """Write `dataset` in `format` (FORMATS) to `out`: a file for ros2, a folder for tum and csv.
    The files written."""
    return {"ros2": export_ros2, "tum": export_tum, "csv": export_csv}[format](dataset, Path(out))


# --- ROS 2 -----------------------------------------------------------------------------------

def message_definition(datatype: str) -> str:
    """The ros2msg schema text of `datatype` (e.g. "sensor_msgs/Imu"): its definition, then each
    definition it uses, each after a separator line and `MSG: <name>`."""
    used = list(dict.fromkeys(_dependencies(datatype)))
    return "\n".join([_DEFINITIONS[datatype], *(f"{SEPARATOR}\nMSG: {name}\n{_DEFINITIONS[name]}" for name in used)])


def _dependencies(datatype: str) -> Iterator[str]:
    for name in _USES.get(datatype, ()):
        yield name
        yield from _dependencies(name)


def schema_name(datatype: str) -> str:
    """"sensor_msgs/Imu" -> "sensor_msgs/msg/Imu", the name ROS 2 tools give the schema."""
    package, name = datatype.split("/")
    return f"{package}/msg/{name}"


def export_ros2(dataset: Dataset, out: Path) -> list[Path]:
    streams = [_imu_messages(dataset), _joint_state_messages(dataset), _tf_messages(dataset),
               _pose_messages(dataset.table(schemas.TRUTH_POSE.name), "/truth/pose"),
               _estimate_pose_messages(dataset)]
    messages = sorted((message for stream in streams for message in stream), key=lambda message: message[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")       # renamed to `out` once complete
    try:
        with partial.open("wb") as stream:
            _write_ros2(stream, [(0, "/tf_static", "tf2_msgs/TFMessage", _imu_mounting(dataset)), *messages],
                        dataset.run_info)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    partial.replace(out)
    return [out]


def _write_ros2(stream, messages: list[tuple], run_info: dict[str, str]) -> None:
    """(log time ns, topic, datatype, message dict) in order, each schema registered when first used."""
    writer = Ros2Writer(stream)
    registered = {}
    for log_ns, topic, datatype, message in messages:
        if datatype not in registered:
            registered[datatype] = writer.register_msgdef(schema_name(datatype), message_definition(datatype))
        writer.write_message(topic, registered[datatype], message, log_time=log_ns, publish_time=log_ns)
    writer.add_metadata("run", run_info)
    writer.finish()


def _stamp(t: float) -> dict[str, int]:
    seconds, nanoseconds = divmod(to_ns(t), NS_PER_S)
    return {"sec": int(seconds), "nanosec": int(nanoseconds)}


def to_ns(t: float) -> int:
    return int(round(float(t) * NS_PER_S))


def _header(t: float, frame: str) -> dict[str, Any]:
    return {"stamp": _stamp(t), "frame_id": frame}


def _xyz(values) -> dict[str, float]:
    x, y, z = values
    return {"x": float(x), "y": float(y), "z": float(z)}


def _xyzw(values) -> dict[str, float]:
    x, y, z, w = values
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


def _columns(table: pandas.DataFrame, prefix: str, suffixes) -> np.ndarray:
    return table[[f"{prefix}{suffix}" for suffix in suffixes]].to_numpy(dtype=float)


def _imu_messages(dataset: Dataset) -> Iterator[tuple]:
    imu = dataset.table(schemas.IMU.name)
    gyro, accel = _columns(imu, "gyro_", "xyz"), _columns(imu, "accel_", "xyz")
    for t, w, f in zip(imu.t.to_numpy(), gyro, accel):
        yield to_ns(t), "/imu", "sensor_msgs/Imu", {
            "header": _header(t, IMU_FRAME), "orientation": _xyzw((0.0, 0.0, 0.0, 1.0)),
            "orientation_covariance": NO_ORIENTATION, "angular_velocity": _xyz(w),
            "angular_velocity_covariance": UNKNOWN_COVARIANCE, "linear_acceleration": _xyz(f),
            "linear_acceleration_covariance": UNKNOWN_COVARIANCE}


def _imu_mounting(dataset: Dataset) -> dict[str, Any]:
    """`body` -> `imu`: the IMU's position and axes in the body frame (sensors.imu)."""
    imu = dataset.config.sensors.imu
    roll, pitch, yaw = np.radians(imu.rpy_deg)
    return {"transforms": [{"header": _header(0.0, BODY_FRAME), "child_frame_id": IMU_FRAME,
                            "transform": {"translation": _xyz(imu.position),
                                          "rotation": _xyzw(spatial.quaternion_from_euler(roll, pitch, yaw))}}]}


def _joint_state_messages(dataset: Dataset) -> Iterator[tuple]:
    names, per_joint = joint_names(), SUFFIXES["positions"]       # the same joint order: leg-major
    encoders = dataset.table(schemas.ENCODERS.name)
    for t, positions in zip(encoders.t.to_numpy(), _columns(encoders, "positions", per_joint)):
        yield to_ns(t), "/joint_states", "sensor_msgs/JointState", {
            "header": _header(t, ""), "name": names, "position": positions.tolist(), "velocity": [], "effort": []}
    state = dataset.table(schemas.TRUTH_STATE.name)
    rows = zip(state.t.to_numpy(), _columns(state, "joint_positions", per_joint),
               _columns(state, "joint_velocities", per_joint))
    for t, positions, velocities in rows:
        yield to_ns(t), "/truth/joint_states", "sensor_msgs/JointState", {
            "header": _header(t, ""), "name": names, "position": positions.tolist(),
            "velocity": velocities.tolist(), "effort": []}


def _tf_messages(dataset: Dataset) -> Iterator[tuple]:
    """The native /tf as tf2_msgs/TFMessage: each frame of its table under its parent (the body
    under `world`, each link under its joint's parent link in the recorded URDF)."""
    table = dataset.table(schemas.TF.name)
    frames = [name.removesuffix(TRANSLATION_X) for name in table.columns if name.endswith(TRANSLATION_X)]
    parents = {BODY_FRAME: WORLD_FRAME, **_link_parents(dataset)}
    frames = [frame for frame in frames if frame in parents]
    translations = [_columns(table, f"{frame}_translation_", "xyz") for frame in frames]
    rotations = [_columns(table, f"{frame}_rotation_", "xyzw") for frame in frames]
    for row, t in enumerate(table.t.to_numpy()):
        yield to_ns(t), "/tf", "tf2_msgs/TFMessage", {"transforms": [
            {"header": _header(t, parents[frame]), "child_frame_id": frame,
             "transform": {"translation": _xyz(translation[row]), "rotation": _xyzw(rotation[row])}}
            for frame, translation, rotation in zip(frames, translations, rotations)]}


def _link_parents(dataset: Dataset) -> dict[str, str]:
    if schemas.ROBOT_DESCRIPTION.name not in dataset.topics:
        return {}
    urdf = dataset.table(schemas.ROBOT_DESCRIPTION.name).data.iloc[0]
    return {joint.child: joint.parent for joint in LinkTree.from_urdf(urdf).joints}


def _pose_messages(table: pandas.DataFrame, topic: str) -> Iterator[tuple]:
    positions, orientations = _columns(table, "position_", "xyz"), _columns(table, "orientation_", "xyzw")
    for t, position, orientation in zip(table.t.to_numpy(), positions, orientations):
        yield to_ns(t), topic, "geometry_msgs/PoseStamped", {
            "header": _header(t, WORLD_FRAME), "pose": {"position": _xyz(position), "orientation": _xyzw(orientation)}}


def _estimate_pose_messages(dataset: Dataset) -> Iterator[tuple]:
    return _pose_messages(estimate_poses(dataset), "/estimate/pose")


def estimate_poses(dataset: Dataset) -> pandas.DataFrame:
    """The estimates as poses: `t`, `position_x/y/z` (the estimated body position, start frame; an
    estimator without one: 0, 0, the estimated height above the support plane or 0) and
    `orientation_x/y/z/w` (the estimated attitude)."""
    estimate = dataset.table(schemas.ESTIMATE.name) if schemas.ESTIMATE.name in dataset.topics else None
    if estimate is None:
        return pandas.DataFrame({name: [] for name in ("t", "position_x", "position_y", "position_z", "orientation_x",
                                                        "orientation_y", "orientation_z", "orientation_w")})
    orientation = {f"orientation_{axis}": estimate[f"quaternion_{axis}"] for axis in "xyzw"}
    if "position_x" in estimate.columns and estimate.position_x.notna().all():
        return pandas.DataFrame({"t": estimate.t, **{f"position_{axis}": estimate[f"position_{axis}"] for axis in "xyz"},
                                 **orientation})
    zeros = np.zeros(len(estimate))
    return pandas.DataFrame({"t": estimate.t, "position_x": zeros, "position_y": zeros,
                             "position_z": estimate.body_height.fillna(0.0), **orientation})


# --- TUM -------------------------------------------------------------------------------------

def export_tum(dataset: Dataset, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "truth.tum", out / "estimate.tum"]
    write_tum(dataset.table(schemas.TRUTH_POSE.name), paths[0])
    write_tum(estimate_poses(dataset), paths[1])
    return paths


def write_tum(poses: pandas.DataFrame, path: Path) -> None:
    """`t x y z qx qy qz qw` per line (TUM RGB-D trajectory format), full precision."""
    columns = ["t", "position_x", "position_y", "position_z", "orientation_x", "orientation_y", "orientation_z",
               "orientation_w"]
    np.savetxt(path, poses[columns].to_numpy(dtype=float), fmt="%.17g", delimiter=" ")


# --- CSV -------------------------------------------------------------------------------------

def export_csv(dataset: Dataset, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for topic in dataset.topics:
        if topic in NOT_TIME_SERIES:
            continue
        path = out / f"{topic.strip('/').replace('/', '_')}.csv"
        dataset.table(topic).to_csv(path, index=False)
        paths.append(path)
    return paths
