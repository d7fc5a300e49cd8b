"""A recorded run as a Rerun recording (.rrd) on the simulation-time timeline `sim_time`.

3D (under /world): the terrain's boxes, the robot from its URDF (the body pose and the 18 joint
angles drive the URDF's frames), the estimated robot as a translucent ghost (the true position
and joint angles, the estimated attitude: where the two differ is the attitude error),
contact-force arrows at the feet, the support polygon, the centre-of-mass projection and the
body's trajectory. Time series (under /plots): true and estimated roll, pitch and yaw with the
estimate's 3-sigma band, the estimated height above the support plane, terrain roll and pitch
and gyro bias with theirs (where the estimator gives them), accelerometer and gyro, joint angles
and the stability margin. A default blueprint lays them out. Every stream is sent as columns
(`rr.send_columns`), one call per entity.

`LiveRerun` streams the same robot, ghost and attitude plots to a Rerun viewer while a run goes
on (`testbed run --rerun-live`), a batch of rows every LIVE_BATCH of simulated time.
"""

from __future__ import annotations

import json
import tempfile
import xml.etree.ElementTree as ElementTree
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from datasets import codec, schemas
from datasets.links import LinkTree
from datasets.reader import Recording, primitive_urdf
from estimators.scoring import roll_pitch_yaw
from sensors.samples import ImuSample

if TYPE_CHECKING:
    from testbed.runtime.config import Config
    from testbed.runtime.recording import Recorder, Tick
    from testbed.world.terrain import Terrain

APP_ID = "hexapod_testbed"
TIMELINE = "sim_time"
WORLD = "world"
WORLD_FRAME = f"tf#/{WORLD}"       # the implicit frame of the /world entity
FORCE_SCALE = 0.01                  # m of arrow per N
CAMERA_OFFSET = np.array([-0.55, -0.75, 0.45])   # m, from the robot's start
TERRAIN_COLOR = (150, 135, 110)
TRUE_COLOR, ESTIMATE_COLOR, BAND_COLOR = (40, 40, 40), (30, 110, 220), (130, 170, 235)
XYZ_COLORS = [(220, 60, 50), (40, 160, 60), (40, 90, 220)]
GHOST = "estimate"                  # entity and frame prefix of the estimated robot
GHOST_RGBA = "0.12 0.43 0.86 0.35"   # the ghost's colour: ESTIMATE_COLOR, translucent
LIVE_RATE = 30.0                    # Hz of simulated time: rows streamed live
TIME_TOLERANCE = 1e-9              # s: a tick this close to a row's time takes it (steps add up inexactly)
LIVE_BATCH = 1.0                    # s of simulated time per batch sent live


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
                                  overrides={f"/{WORLD}/hexapod/collision_geometries": rrb.EntityBehavior(visible=False),
                                             f"/{WORLD}/hexapod_{GHOST}/collision_geometries":
                                                 rrb.EntityBehavior(visible=False)}),
                rrb.TextDocumentView(name="Run", origin="/run", contents="$origin"),
                row_shares=[4, 1]),
            rrb.Vertical(
                series("Roll (deg): truth, estimate +- 3 sigma", "/plots/attitude/roll"),
                series("Pitch (deg): truth, estimate +- 3 sigma", "/plots/attitude/pitch"),
                rrb.Tabs(series("Yaw (deg): truth, estimate +- 3 sigma", "/plots/attitude/yaw"),
                         series("Height above the support plane (m), +- 3 sigma", "/plots/height"),
                         series("Terrain roll and pitch (deg), +- 3 sigma", "/plots/terrain"),
                         series("Gyro bias (deg/s), +- 3 sigma", "/plots/gyro_bias"),
                         series("Accelerometer (m/s^2)", "/plots/imu/accel"),
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
    log_terrain_boxes(rec, boxes.centers, boxes.sizes / 2, boxes.quaternions)


def log_terrain_boxes(rec: rr.RecordingStream, centers: np.ndarray, half_sizes: np.ndarray,
                      quaternions: np.ndarray) -> None:
    rec.log(f"{WORLD}/terrain", rr.Boxes3D(centers=centers, half_sizes=half_sizes, quaternions=quaternions,
                                            colors=TERRAIN_COLOR, fill_mode=rr.components.FillMode.Solid), static=True)


def _log_robot(rec: rr.RecordingStream, recording: Recording, states: list) -> None:
    """The URDF's links, placed by the body pose and the joint angles; its ghost at the estimated
    attitude; the body's trajectory."""
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
    estimates = recording.estimates()
    model = RobotModel.log(rec, urdf, ghost=bool(estimates))
    body_t = np.array([s.t for s in states]) if states else t
    index = np.clip(np.searchsorted(t, body_t), 0, len(t) - 1)
    joints = np.array([s.joint_positions for s in states]) if states else None
    estimated = None
    if estimates:
        est_t = np.array([e.t for e in estimates])
        nearest = np.clip(np.searchsorted(est_t, body_t), 0, len(est_t) - 1)
        estimated = np.array([estimates[k].quaternion for k in nearest])
    model.send(rec, body_t, positions[index], quaternions[index], joints, estimated)


class RobotModel:
    """The robot of a Rerun recording: the URDF's links in frames named after them (`body`,
    `legN_coxa`, ...) and, as a translucent ghost, a second copy in frames prefixed `estimate/`."""

    def __init__(self, tree, ghost_tree, links: LinkTree):
        self.tree, self.ghost_tree, self.links = tree, ghost_tree, links
        self.root = tree.root_link().name

    @classmethod
    def log(cls, rec: rr.RecordingStream, urdf: str, ghost: bool) -> "RobotModel":
        """Log the URDF's geometry (static), and the ghost's when `ghost`."""
        tree = _log_urdf(rec, urdf, WORLD)
        ghost_tree = _log_urdf(rec, ghost_urdf(urdf), WORLD, frame_prefix=f"{GHOST}/") if ghost else None
        return cls(tree, ghost_tree, LinkTree.from_urdf(urdf))

    def send(self, rec: rr.RecordingStream, t: np.ndarray, positions: np.ndarray, quaternions: np.ndarray,
             joint_positions: np.ndarray | None, estimated: np.ndarray | None) -> None:
        """The body's pose and joint angles at times `t` (the ghost: the estimated attitude
        `estimated` at the true position, the same joint angles). Each robot's joints are one
        entity whose rows at a time are the 18 parent -> child link transforms."""
        self._send_pose(rec, "transforms/body", t, positions, quaternions, self.root)
        ghost = estimated is not None and self.ghost_tree is not None
        if ghost:
            self._send_pose(rec, f"transforms/{GHOST}/body", t, positions, estimated, f"{GHOST}/{self.root}")
        if joint_positions is None:
            return
        rotations = np.array([self.links.rotations(row) for row in joint_positions])     # (N, 18, 4)
        for entity, prefix in (("transforms/joints", ""), (f"transforms/{GHOST}/joints", f"{GHOST}/"))[:1 + ghost]:
            joints = self.links.joints
            _send(rec, entity, np.repeat(t, len(joints)), rr.Transform3D.columns(
                translation=np.tile([joint.translation for joint in joints], (len(t), 1)),
                quaternion=rotations.reshape(-1, 4),
                parent_frame=[prefix + joint.parent for joint in joints] * len(t),
                child_frame=[prefix + joint.child for joint in joints] * len(t)))

    @staticmethod
    def _send_pose(rec, entity: str, t, positions, quaternions, child: str) -> None:
        _send(rec, entity, t, rr.Transform3D.columns(translation=positions, quaternion=quaternions,
                                                     parent_frame=[WORLD_FRAME] * len(t), child_frame=[child] * len(t)))


def ghost_urdf(urdf: str) -> str:
    """The URDF of the ghost: every colour GHOST_RGBA, the robot renamed `<name>_estimate` (its
    entities are /world/<name>_estimate/...)."""
    robot = ElementTree.fromstring(urdf)
    robot.set("name", f"{robot.get('name')}_{GHOST}")
    for color in robot.iter("color"):
        color.set("rgba", GHOST_RGBA)
    return ElementTree.tostring(robot, encoding="unicode")


def _log_urdf(rec: rr.RecordingStream, urdf: str, entity: str, frame_prefix: str | None = None):
    with tempfile.TemporaryDirectory() as folder:
        urdf_path = Path(folder) / "robot.urdf"
        urdf_path.write_text(urdf)
        tree = rr.urdf.UrdfTree.from_file_path(urdf_path, entity_path_prefix=entity, frame_prefix=frame_prefix)
        tree.log_urdf_to_recording(rec)
    return tree


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


_STYLED: dict[str, set[str]] = {}     # per recording id: the series whose style is logged already


def _series(rec: rr.RecordingStream, entity: str, t: np.ndarray, values: np.ndarray, names: list[str],
            colors: list[tuple[int, int, int]], widths: list[float] | None = None) -> None:
    styled = _STYLED.setdefault(rec.get_recording_id(), set())
    if entity not in styled:
        styled.add(entity)
        rec.log(entity, rr.SeriesLines(names=names, colors=colors, widths=widths or [1.5] * len(names)), static=True)
    _send(rec, entity, t, rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def _log_attitude(rec: rr.RecordingStream, recording: Recording) -> None:
    t, _, quaternions = recording.poses()
    if len(t):
        send_true_attitude(rec, t, quaternions)
    estimates = recording.estimates()
    if estimates:
        send_estimates(rec, estimates)


def send_true_attitude(rec: rr.RecordingStream, t: np.ndarray, quaternions: np.ndarray) -> None:
    """True roll, pitch and yaw (deg)."""
    true_rpy = np.degrees(roll_pitch_yaw(Rotation.from_quat(quaternions).as_matrix()))
    for axis, name in enumerate(("roll", "pitch", "yaw")):
        _series(rec, f"plots/attitude/{name}/truth", t, true_rpy[:, axis:axis + 1], [f"true {name}"], [TRUE_COLOR])


def send_estimates(rec: rr.RecordingStream, estimates: list) -> None:
    """Estimated roll, pitch, yaw (deg), height above the support plane (m), terrain roll and pitch
    (deg) and gyro bias (deg/s), each with its +- 3 sigma band where the estimator gives a covariance."""
    t = np.array([e.t for e in estimates])
    attitude_sigma = _sigmas([e.attitude_cov for e in estimates], 3)
    for axis, name in enumerate(("roll", "pitch", "yaw")):
        values = np.degrees([getattr(e, name) for e in estimates])
        _with_band(rec, f"plots/attitude/{name}", t, values, np.degrees(attitude_sigma[:, axis]), f"estimated {name}")
    terrain_sigma = _sigmas([e.terrain_cov for e in estimates], 3)
    height = np.array([np.nan if e.body_height is None else e.body_height for e in estimates])
    if np.isfinite(height).any():
        _with_band(rec, "plots/height", t, height, terrain_sigma[:, 2], "estimated height above the support plane")
    for axis, name in enumerate(("terrain_roll", "terrain_pitch")):
        values = np.degrees([np.nan if getattr(e, name) is None else getattr(e, name) for e in estimates])
        if np.isfinite(values).any():
            _with_band(rec, f"plots/terrain/{name.removeprefix('terrain_')}", t, values,
                       np.degrees(terrain_sigma[:, axis]), name.replace("_", " "))
    bias = np.array([np.full(3, np.nan) if e.gyro_bias is None else e.gyro_bias for e in estimates], dtype=float)
    bias_sigma = _sigmas([e.gyro_bias_cov for e in estimates], 3)
    for axis, name in enumerate("xyz"):
        if np.isfinite(bias[:, axis]).any():
            _with_band(rec, f"plots/gyro_bias/{name}", t, np.degrees(bias[:, axis]), np.degrees(bias_sigma[:, axis]),
                       f"gyro bias {name}")


def _sigmas(covariances: list, size: int) -> np.ndarray:
    """(N, size): the square roots of each covariance's diagonal (NaN where there is none)."""
    return np.sqrt(np.array([np.full(size, np.nan) if c is None else np.diag(np.asarray(c).reshape(size, size))
                             for c in covariances], dtype=float).reshape(-1, size))


def _with_band(rec: rr.RecordingStream, entity: str, t: np.ndarray, values: np.ndarray, sigma: np.ndarray,
               label: str) -> None:
    _series(rec, f"{entity}/estimate", t, values[:, None], [label], [ESTIMATE_COLOR], [2.0])
    if np.isfinite(sigma).any():
        band = np.column_stack([values + 3 * sigma, values - 3 * sigma])
        _series(rec, f"{entity}/band_3sigma", t, band, ["+3 sigma", "-3 sigma"], [BAND_COLOR, BAND_COLOR], [1.0, 1.0])


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


class LiveRerun:
    """A recorder (`testbed.runtime.recording.Recorder`) that also streams the run to a Rerun
    viewer while it runs: the terrain, the robot and its ghost, the true and estimated attitude and
    the estimator's other plots, sampled at LIVE_RATE of simulated time and sent in batches every
    LIVE_BATCH (`rr.send_columns`: a few calls per batch, not per tick). `url` is a viewer's gRPC
    address (`rerun+http://HOST:PORT/proxy`); without one a viewer is spawned."""

    def __init__(self, inner: "Recorder", url: str | None = None):
        self.inner, self.url = inner, url
        self.path = getattr(inner, "path", None)       # the file recorded to, if any
        self.rec: rr.RecordingStream | None = None
        self.model: RobotModel | None = None
        self._rows: list[tuple] = []        # (t, body position, quaternion, joint positions, estimate or None)
        self._latest = None                 # the last estimate so far
        self._next_row = 0.0
        self._next_batch = LIVE_BATCH

    def start(self, config: "Config", urdf: str, terrain: "Terrain") -> None:
        self.inner.start(config, urdf, terrain)
        self.rec = rr.RecordingStream(APP_ID, recording_id=f"live-{uuid.uuid4()}")
        layout = blueprint(np.zeros(3))
        if self.url is None:
            self.rec.spawn(default_blueprint=layout)
        else:
            self.rec.connect_grpc(self.url, default_blueprint=layout)
        boxes = terrain.boxes
        if len(boxes.centers):
            log_terrain_boxes(self.rec, boxes.centers, boxes.half_extents, Rotation.from_matrix(boxes.rotations).as_quat())
        self.model = RobotModel.log(self.rec, urdf, ghost=config.run.estimator != "none")
        _prepare_columns()

    def record(self, tick: "Tick") -> None:
        self.inner.record(tick)
        if tick.estimates:
            self._latest = tick.estimates[-1]
        t = tick.truth.t
        if t + TIME_TOLERANCE >= self._next_row:
            self._next_row += 1.0 / LIVE_RATE
            truth = tick.truth
            self._rows.append((t, truth.body_position.copy(), tick.truth_quaternion.copy(),
                               truth.joint_positions.copy(), self._latest))
        if t + TIME_TOLERANCE >= self._next_batch:
            self._next_batch += LIVE_BATCH
            self._send()

    def finish(self, metrics: dict, error: str | None) -> None:
        try:
            self.inner.finish(metrics, error)
        finally:
            if self.rec is not None:
                self._send()
                self.rec.flush()
                self.rec.disconnect()

    def _send(self) -> None:
        if not self._rows:
            return
        t, positions, quaternions, joints, estimates = zip(*self._rows)
        self._rows = []
        t, quaternions = np.array(t), np.array(quaternions)
        known = [e is not None for e in estimates]
        estimated = np.array([e.quaternion if e is not None else q for e, q in zip(estimates, quaternions)])
        self.model.send(self.rec, t, np.array(positions), quaternions, np.array(joints),
                        estimated if any(known) else None)
        _send(self.rec, f"{WORLD}/body_position", t, rr.Points3D.columns(positions=np.array(positions),
                                                                          radii=[0.006] * len(t)))
        send_true_attitude(self.rec, t, quaternions)
        if any(known):
            send_estimates(self.rec, [e for e in estimates if e is not None])


def _prepare_columns() -> None:
    """Build (and drop) one row of each column type streamed live: rerun sets up its first
    Transform3D columns lazily, in about a second, which belongs before the run, not inside it."""
    rr.Transform3D.columns(translation=np.zeros((1, 3)), quaternion=[(0.0, 0.0, 0.0, 1.0)], parent_frame=[WORLD_FRAME],
                           child_frame=[WORLD_FRAME])
    rr.Points3D.columns(positions=np.zeros((1, 3)), radii=[0.0])
    rr.Scalars.columns(scalars=np.zeros((1, 1)))
