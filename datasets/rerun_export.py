"""A recorded run as a Rerun recording (.rrd) on the simulation-time timeline `sim_time`.

3D (under /world): the terrain's boxes, the robot from its URDF (the body pose and the 18 joint
angles drive the URDF's frames), contact-force arrows at the feet, the support polygon, the
centre-of-mass projection and the body's trajectory. Time series (under /plots): true and
estimated roll and pitch with the estimate's 3-sigma band, accelerometer and gyro, joint angles
and the stability margin. A default blueprint lays them out. Every stream is sent as columns
(`rr.send_columns`), one call per entity.
"""

from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from datasets import codec, schemas
from datasets.reader import Recording, primitive_urdf
from estimators.scoring import roll_pitch_yaw
from sensors.samples import ImuSample

APP_ID = "hexapod_testbed"
TIMELINE = "sim_time"
WORLD = "world"
WORLD_FRAME = f"tf#/{WORLD}"       # the implicit frame of the /world entity
FORCE_SCALE = 0.01                  # m of arrow per N
CAMERA_OFFSET = np.array([-0.55, -0.75, 0.45])   # m, from the robot's start
TERRAIN_COLOR = (150, 135, 110)
TRUE_COLOR, ESTIMATE_COLOR, BAND_COLOR = (40, 40, 40), (30, 110, 220), (130, 170, 235)
XYZ_COLORS = [(220, 60, 50), (40, 160, 60), (40, 90, 220)]
JOINT_NAME = re.compile(r"leg(\d+)_joint(\d+)$")


def export_rrd(recording: Recording, rrd_path: str | Path) -> Path:
    """Write `rrd_path` (through a temporary file, renamed when complete)."""
    rrd_path = Path(rrd_path)
    partial = rrd_path.with_name(rrd_path.name + ".partial")
    _, positions, _ = recording.poses()
    rec = rr.RecordingStream(APP_ID, recording_id=_recording_id(recording))
    try:
        rec.save(partial, default_blueprint=blueprint(positions[0] if len(positions) else np.zeros(3)))
        try:
            _log_run(rec, recording)
        finally:
            rec.disconnect()
        partial.replace(rrd_path)
    except BaseException:
        partial.unlink(missing_ok=True)     # nothing half-written is left behind
        raise
    return rrd_path


def blueprint(robot_start: np.ndarray) -> rrb.Blueprint:
    """The default layout; the 3D camera starts behind and above the robot's start and follows it."""
    def series(name: str, origin: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=name, origin=origin)

    camera = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=robot_start + CAMERA_OFFSET,
                               look_target=robot_start, eye_up=(0.0, 0.0, 1.0),
                               tracking_entity=f"/{WORLD}/body_position")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name="Robot and terrain", origin=f"/{WORLD}", eye_controls=camera,
                                  overrides={f"/{WORLD}/hexapod/collision_geometries": rrb.EntityBehavior(visible=False)}),
                rrb.TextDocumentView(name="Run", origin="/run", contents="$origin"),
                row_shares=[4, 1]),
            rrb.Vertical(
                series("Roll (deg): truth, estimate +- 3 sigma", "/plots/attitude/roll"),
                series("Pitch (deg): truth, estimate +- 3 sigma", "/plots/attitude/pitch"),
                rrb.Tabs(series("Accelerometer (m/s^2)", "/plots/imu/accel"),
                         series("Gyro (rad/s)", "/plots/imu/gyro"),
                         series("Joint angles (rad)", "/plots/joints"),
                         series("Stability margin (m)", "/plots/stability_margin")),
                row_shares=[1, 1, 1]),
            column_shares=[3, 2]),
        collapse_panels=True)


def _recording_id(recording: Recording) -> str:
    run = recording.run_info()
    return f"{recording.path.stem}-{run.get('created_utc', '')}"


def _log_run(rec: rr.RecordingStream, recording: Recording) -> None:
    _log_summary(rec, recording)
    _log_terrain(rec, recording)
    states = recording.truth_states()
    _log_robot(rec, recording, states)
    _log_contacts(rec, recording)
    _log_support(rec, recording)
    _log_attitude(rec, recording)
    _log_imu(rec, recording)
    _log_joints(rec, states)


def _send(rec: rr.RecordingStream, entity: str, t: np.ndarray, columns) -> None:
    if len(t):
        rr.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))],
                        columns=columns, recording=rec)


def _log_summary(rec: rr.RecordingStream, recording: Recording) -> None:
    run = recording.run_info()
    metrics = recording.metrics()
    lines = [f"# {recording.path.name}", "",
             f"terrain **{run.get('terrain', '?')}**, estimator **{run.get('estimator', '?')}**, "
             f"gait {run.get('gait', '?')}, seed {run.get('seed', '?')}", ""]
    if recording.outcome().get("error"):
        lines += [f"stopped early: {recording.outcome()['error']}", ""]
    if metrics is not None:
        lines += ["| metric | value |", "|---|---|"] + [f"| {key} | {value} |" for key, value in sorted(metrics.items())]
    rec.log("run", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)
    rec.log("run/config", rr.TextDocument(json.dumps(_safe_config(recording), indent=1)), static=True)


def _safe_config(recording: Recording) -> dict:
    try:
        return recording.config_dict()
    except Exception:  # noqa: BLE001 - a view of a foreign file shows no config rather than failing
        return {}


def _log_terrain(rec: rr.RecordingStream, recording: Recording) -> None:
    boxes = recording.terrain()
    if boxes is None or not len(boxes.centers):
        return
    rec.log(f"{WORLD}/terrain", rr.Boxes3D(centers=boxes.centers, half_sizes=boxes.sizes / 2,
                                            quaternions=boxes.quaternions, colors=TERRAIN_COLOR,
                                            fill_mode=rr.components.FillMode.Solid), static=True)


def _log_robot(rec: rr.RecordingStream, recording: Recording, states: list) -> None:
    """The URDF's links, placed by the body pose and the joint angles; the body's trajectory."""
    t, positions, quaternions = recording.poses()
    if not len(t):
        return
    rec.log(f"{WORLD}/trajectory", rr.LineStrips3D([positions[:: max(1, len(t) // 5000)]], colors=(230, 150, 30),
                                                     radii=0.002), static=True)
    _send(rec, f"{WORLD}/body_position", t[::5], rr.Points3D.columns(positions=positions[::5], radii=[0.006] * len(t[::5])))
    urdf = recording.urdf()
    if not urdf:
        return
    primitive_urdf(urdf, recording.path)
    with tempfile.TemporaryDirectory() as folder:
        urdf_path = Path(folder) / "robot.urdf"
        urdf_path.write_text(urdf)
        tree = rr.urdf.UrdfTree.from_file_path(urdf_path, entity_path_prefix=WORLD)
        tree.log_urdf_to_recording(rec)
    root = tree.root_link().name
    body_t = np.array([s.t for s in states]) if states else t
    index = np.clip(np.searchsorted(t, body_t), 0, len(t) - 1)
    _send(rec, "transforms/body", body_t, rr.Transform3D.columns(
        translation=positions[index], quaternion=quaternions[index],
        parent_frame=[WORLD_FRAME] * len(body_t), child_frame=[root] * len(body_t)))
    if not states:
        return
    joint_positions = np.array([s.joint_positions for s in states])
    for joint in tree.joints():
        match = JOINT_NAME.match(joint.name)
        if joint.joint_type != "revolute" or match is None:
            continue
        column = 3 * (int(match[1]) - 1) + int(match[2]) - 1
        _send(rec, f"transforms/{joint.name}", body_t,
              joint.compute_transform_columns(joint_positions[:, column].tolist(), clamp=False))


def _log_contacts(rec: rr.RecordingStream, recording: Recording) -> None:
    contacts = recording.contacts()
    if not contacts:
        return
    t = np.array([c[0] for c in contacts])
    points = np.concatenate([c[1].points for c in contacts])
    forces = np.concatenate([np.where(c[1].in_contact[:, None], c[1].forces, 0.0) for c in contacts])
    lengths = [len(c[1].points) for c in contacts]
    _send(rec, f"{WORLD}/contact_forces", t, rr.Arrows3D.columns(
        origins=points, vectors=forces * FORCE_SCALE, colors=[(230, 40, 40)] * len(points)).partition(lengths))


def _log_support(rec: rr.RecordingStream, recording: Recording) -> None:
    supports = recording.supports()
    contacts = {round(t, 9): c for t, c in recording.contacts()}
    if not supports:
        return
    t = np.array([s.t for s in supports])
    ground = np.array([_ground_height(contacts.get(round(s.t, 9))) for s in supports])
    strips = [np.column_stack([np.vstack([s.polygon, s.polygon[:1]]), np.full(len(s.polygon) + 1, z)])
              if len(s.polygon) else np.zeros((0, 3)) for s, z in zip(supports, ground)]
    _send(rec, f"{WORLD}/support_polygon", t, rr.LineStrips3D.columns(strips=strips, colors=[(40, 170, 60)] * len(t),
                                                                         radii=[0.002] * len(t)))
    com = np.column_stack([np.array([s.com_projection for s in supports]).reshape(-1, 2), ground])
    _send(rec, f"{WORLD}/com_projection", t, rr.Points3D.columns(positions=com, colors=[(200, 40, 200)] * len(t),
                                                                    radii=[0.008] * len(t)))
    _series(rec, "plots/stability_margin", t, np.array([[s.stability_margin] for s in supports]), ["margin"],
            [(40, 170, 60)])


def _ground_height(contacts) -> float:
    if contacts is None or not contacts.in_contact.any():
        return 0.0
    return float(np.mean(contacts.points[contacts.in_contact, 2]))


def _series(rec: rr.RecordingStream, entity: str, t: np.ndarray, values: np.ndarray, names: list[str],
            colors: list[tuple[int, int, int]], widths: list[float] | None = None) -> None:
    rec.log(entity, rr.SeriesLines(names=names, colors=colors, widths=widths or [1.5] * len(names)), static=True)
    _send(rec, entity, t, rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def _log_attitude(rec: rr.RecordingStream, recording: Recording) -> None:
    t, _, quaternions = recording.poses()
    if len(t):
        true_rpy = np.degrees(roll_pitch_yaw(Rotation.from_quat(quaternions).as_matrix()))
        for axis, name in enumerate(("roll", "pitch")):
            _series(rec, f"plots/attitude/{name}/truth", t, true_rpy[:, axis:axis + 1], [f"true {name}"], [TRUE_COLOR])
    estimates = recording.estimates()
    if not estimates:
        return
    est_t = np.array([e.t for e in estimates])
    angles = np.degrees(np.array([[e.roll, e.pitch] for e in estimates]))
    sigma = np.degrees(np.sqrt(np.array([np.diag(e.attitude_cov)[:2] if e.attitude_cov is not None
                                         else (np.nan, np.nan) for e in estimates])))
    for axis, name in enumerate(("roll", "pitch")):
        _series(rec, f"plots/attitude/{name}/estimate", est_t, angles[:, axis:axis + 1], [f"estimated {name}"],
                [ESTIMATE_COLOR], [2.0])
        if np.isfinite(sigma[:, axis]).any():
            band = np.column_stack([angles[:, axis] + 3 * sigma[:, axis], angles[:, axis] - 3 * sigma[:, axis]])
            _series(rec, f"plots/attitude/{name}/band_3sigma", est_t, band, ["+3 sigma", "-3 sigma"],
                    [BAND_COLOR, BAND_COLOR], [1.0, 1.0])


def _log_imu(rec: rr.RecordingStream, recording: Recording) -> None:
    imu = [s for s in (codec.decode_sample(schemas.IMU.name, data)
                       for _, _, data in recording.messages.get(schemas.IMU.name, [])) if isinstance(s, ImuSample)]
    if not imu:
        return
    t = np.array([s.t for s in imu])
    _series(rec, "plots/imu/accel", t, np.array([s.accel for s in imu]), ["x", "y", "z"], XYZ_COLORS)
    _series(rec, "plots/imu/gyro", t, np.array([s.gyro for s in imu]), ["x", "y", "z"], XYZ_COLORS)


def _log_joints(rec: rr.RecordingStream, states: list) -> None:
    if not states:
        return
    t = np.array([s.t for s in states])
    joints = np.array([s.joint_positions for s in states])
    for leg in range(joints.shape[1] // 3):
        _series(rec, f"plots/joints/leg{leg + 1}", t, joints[:, 3 * leg:3 * leg + 3],
                [f"leg {leg + 1} coxa", f"leg {leg + 1} femur", f"leg {leg + 1} tibia"], XYZ_COLORS)
