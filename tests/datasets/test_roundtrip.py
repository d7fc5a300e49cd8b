"""Record -> read gives back every stream bit for bit, plus the run description; mcap's own reader
decodes the file by the schemas it carries, and it passes rerun's MCAP check."""

from __future__ import annotations

import json

from collections import defaultdict

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from datasets import schemas
from datasets import codec
from datasets.reader import REPLAY_TOPICS, read_description, read_recording
from sensors.samples import AccelSample, EncoderSample, FootSample, ImuSample
from tests.datasets.conftest import record, run_rerun
from tests.datasets.ticks import generate_ticks, synthetic_config
from testbed.model.robot import build_urdf

ARRAY_FIELDS = {"ImuSample": ("accel", "gyro"), "AccelSample": ("accel",), "EncoderSample": ("positions",),
                "FootSample": ("normal_forces", "contact")}


def assert_same_sample(read, written) -> None:
    assert type(read) is type(written) and read.t == written.t
    if isinstance(read, AccelSample):
        assert read.index == written.index
    for name in ARRAY_FIELDS[type(read).__name__]:
        a, b = getattr(read, name), getattr(written, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name     # bytes: NaN payloads too


def assert_same_estimate(read, written) -> None:
    for name in ("t", "roll", "pitch", "yaw", "terrain_roll", "terrain_pitch", "body_height"):
        assert getattr(read, name) == getattr(written, name), name
    for name in ("quaternion", "attitude_cov", "gyro_bias", "gyro_bias_cov", "terrain_cov", "position", "velocity",
                 "position_cov", "velocity_cov"):
        a, b = getattr(read, name), getattr(written, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert a.shape == b.shape and a.tobytes() == b.tobytes(), name


def test_every_sample_comes_back_bit_for_bit_in_handing_order(ekf_run):
    _, ticks, path = ekf_run
    written = [sample for tick in ticks for sample in tick.samples]
    read = read_recording(path).samples()
    assert len(read) == len(written)
    for a, b in zip(read, written):
        assert_same_sample(a, b)
    assert any(isinstance(s, ImuSample) and np.isnan(s.accel).any() for s in read)
    assert any(isinstance(s, FootSample) and not s.contact.any() for s in read)


def test_every_estimate_comes_back_bit_for_bit(ekf_run):
    _, ticks, path = ekf_run
    written = [estimate for tick in ticks for estimate in tick.estimates]
    read = read_recording(path).estimates()
    assert len(read) == len(written) > 1000
    for a, b in zip(read, written):
        assert_same_estimate(a, b)
    assert any(e.terrain_roll is None for e in read) and any(e.terrain_roll is not None for e in read)
    assert all(e.position.shape == (3,) and e.velocity_cov.shape == (3, 3) for e in read)     # the full state


def test_estimates_without_covariance_come_back_as_none(tmp_path):
    config = synthetic_config("complementary")
    ticks = list(generate_ticks(config, 0.2))
    path = tmp_path / "c.mcap"
    record(path, config, ticks)
    written = [estimate for tick in ticks for estimate in tick.estimates]
    read = read_recording(path).estimates()
    assert len(read) == len(written) and written[0].attitude_cov is None and read[0].position is None
    for a, b in zip(read, written):
        assert_same_estimate(a, b)


def test_truth_and_commands_come_back_at_the_truth_rate(ekf_run):
    _, ticks, path = ekf_run
    recording = read_recording(path)
    every = int(recording.run_info()["truth_every"])
    assert every == 5 and float(recording.run_info()["truth_rate_hz"]) == 200.0
    expected = ticks[::every]
    states, contacts, supports, commands = (recording.truth_states(), recording.contacts(), recording.supports(),
                                            recording.commands())
    assert len(states) == len(contacts) == len(supports) == len(commands) == len(expected)
    for tick, state, (t, contact), support, command in zip(expected, states, contacts, supports, commands):
        for name in ("body_position", "body_rotation", "body_linear_velocity", "body_angular_velocity",
                     "body_linear_acceleration", "body_angular_acceleration", "joint_positions", "joint_velocities",
                     "foot_positions", "foot_forces", "foot_normal_forces", "foot_contact", "com_position"):
            np.testing.assert_array_equal(getattr(state, name), getattr(tick.truth, name), err_msg=name)
        assert state.t == t == support.t == tick.truth.t
        for name in ("points", "normals", "forces", "normal_forces", "in_contact"):
            np.testing.assert_array_equal(getattr(contact, name), getattr(tick.contacts, name), err_msg=name)
        np.testing.assert_array_equal(support.polygon, tick.support_polygon)
        np.testing.assert_array_equal(support.com_projection, tick.truth.com_position[:2])
        assert support.stability_margin == tick.stability_margin
        for name in ("t", "phase", "swinging", "foot_targets", "joint_targets", "body_twist"):
            np.testing.assert_array_equal(getattr(command, name), getattr(tick.command, name), err_msg=name)


def test_pose_and_feet_are_recorded_at_every_physics_step(ekf_run):
    _, ticks, path = ekf_run
    truth = read_recording(path).scoring_truth()
    assert len(truth.t) == len(ticks)
    np.testing.assert_array_equal(truth.t, [tick.truth.t for tick in ticks])
    np.testing.assert_array_equal(truth.quaternion, [tick.truth_quaternion for tick in ticks])
    np.testing.assert_array_equal(truth.body_position, [tick.truth.body_position for tick in ticks])
    np.testing.assert_array_equal(truth.foot_positions, [tick.truth.foot_positions for tick in ticks])
    np.testing.assert_array_equal(truth.foot_contact, [tick.truth.foot_contact for tick in ticks])


def test_log_times_are_simulation_nanoseconds(ekf_run):
    _, ticks, path = ekf_run
    recording = read_recording(path)
    log_ns = [entry[0] for entry in recording.messages[schemas.TRUTH_POSE.name]]
    assert log_ns == [round(tick.truth.t * 1e9) for tick in ticks]
    imu = recording.messages[schemas.IMU.name]
    assert all(np.diff([entry[0] for entry in imu]) > 0)
    assert recording.topics[schemas.IMU.name].rate_hz == pytest.approx(1000.0)


def test_the_file_describes_and_reproduces_its_run(ekf_run):
    config, _, path = ekf_run
    recording = read_recording(path)
    assert recording.config() == config
    assert recording.urdf() == build_urdf(config.robot)
    assert recording.attachments["config.toml"].decode() == config.to_toml()
    assert recording.metrics() == {"roll_rmse_deg": 0.5}
    assert recording.outcome()["error"] == ""
    assert recording.run_info()["terrain"] == "flat" and recording.run_info()["estimator"] == "ekf"
    versions = recording.metadata["versions"]
    assert versions["mcap"] and versions["numpy"] and versions["python"]
    assert recording.terrain().centers.shape == (1, 3)
    assert read_description(path).config_dict() == json.loads(json.dumps(config.to_dict()))


def test_poses_use_foxglove_schemas_and_the_rest_protobuf(ekf_run):
    _, _, path = ekf_run
    topics = read_recording(path, topics=()).topics
    assert topics["/truth/pose"].schema == "foxglove.PoseInFrame"
    assert topics["/tf"].schema == "foxglove.FrameTransforms"
    assert topics["/robot_description"].schema == "hexapod.RobotDescription"
    assert topics["/terrain"].schema == "foxglove.SceneUpdate"
    assert topics["/estimate"].schema == "hexapod.Estimate"


def test_the_file_gets_its_final_name_only_when_finished(tmp_path):
    from datasets.recorder import McapRecorder
    from tests.datasets.ticks import terrain_and_urdf

    config = synthetic_config("complementary")
    recorder = McapRecorder(tmp_path / "run.mcap")
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    for tick in generate_ticks(config, 0.1):
        recorder.record(tick)
    assert recorder.partial_path.exists() and not recorder.path.exists()
    recorder.finish({}, "interrupted at t = 0.100 s")
    recorder.finish({}, None)          # a second call changes nothing
    assert recorder.path.exists() and not recorder.partial_path.exists()
    assert read_recording(recorder.path).outcome()["error"] == "interrupted at t = 0.100 s"


def test_rerun_mcap_check_passes(ekf_run):
    _, _, path = ekf_run
    result = run_rerun("mcap", "check", str(path))
    assert result.returncode == 0, result.stdout + result.stderr


def test_mcap_reader_decodes_every_message_by_the_schemas_in_the_file(ekf_run):
    """mcap's reader and mcap-protobuf's decoder, which know nothing of this project, read back the
    values that were recorded, each topic in order, with the counts of the file's summary."""
    _, ticks, path = ekf_run
    decoded = defaultdict(list)
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _, channel, message, proto in reader.iter_decoded_messages(log_time_order=False):
            assert message.publish_time == message.log_time
            decoded[channel.topic].append((message.sequence, proto))
    topics = {channel.id: channel.topic for channel in summary.channels.values()}
    counts = {topics[channel]: count for channel, count in summary.statistics.channel_message_counts.items()}
    assert counts == {topic: len(messages) for topic, messages in decoded.items()}
    assert summary.statistics.message_count == read_recording(path).message_count()

    samples = [sample for tick in ticks for sample in tick.samples]
    in_order = sorted((sequence, topic, proto) for topic in schemas.SENSOR_TOPICS
                      for sequence, proto in decoded[topic])
    assert [sequence for sequence, _, _ in in_order] == list(range(len(samples)))
    fields = {ImuSample: ("accel", "gyro"), AccelSample: ("accel",), EncoderSample: ("positions",),
              FootSample: ("normal_forces", "contact")}
    for (_, _, proto), sample in zip(in_order, samples):
        assert proto.t == sample.t
        for name in fields[type(sample)]:
            np.testing.assert_array_equal(np.array(getattr(proto, name)), getattr(sample, name), err_msg=name)

    estimates = [estimate for tick in ticks for estimate in tick.estimates]
    assert len(decoded[schemas.ESTIMATE.name]) == len(estimates)
    for (_, proto), estimate in zip(decoded[schemas.ESTIMATE.name], estimates):
        assert (proto.t, proto.roll, proto.pitch, proto.yaw) == (estimate.t, estimate.roll, estimate.pitch, estimate.yaw)
        np.testing.assert_allclose(proto.quaternion, estimate.quaternion, rtol=0, atol=0)
        np.testing.assert_allclose(np.reshape(proto.attitude_cov, (3, 3)), estimate.attitude_cov, rtol=0, atol=0)
        assert proto.HasField("terrain_roll") == (estimate.terrain_roll is not None)

    poses = decoded[schemas.TRUTH_POSE.name]
    assert len(poses) == len(ticks)
    for (_, proto), tick in zip(poses, ticks):
        position, orientation = proto.pose.position, proto.pose.orientation
        np.testing.assert_allclose([position.x, position.y, position.z], tick.truth.body_position, rtol=0, atol=0)
        np.testing.assert_allclose([orientation.x, orientation.y, orientation.z, orientation.w],
                                   tick.truth_quaternion, rtol=0, atol=0)
        assert proto.timestamp.seconds * 10**9 + proto.timestamp.nanos == round(tick.truth.t * 1e9)

    heavy = ticks[::5]
    assert len(decoded[schemas.TRUTH_STATE.name]) == len(decoded[schemas.TF.name]) == len(heavy)
    for (_, proto), tick in zip(decoded[schemas.TRUTH_STATE.name], heavy):
        assert proto.t == tick.truth.t
        np.testing.assert_allclose(np.reshape(proto.body_rotation, (3, 3)), tick.truth.body_rotation, rtol=0, atol=0)
        np.testing.assert_allclose(proto.joint_positions, tick.truth.joint_positions, rtol=0, atol=0)
        np.testing.assert_array_equal(proto.foot_contact, tick.truth.foot_contact)
    for (_, proto), tick in zip(decoded[schemas.COMMAND.name], heavy):
        np.testing.assert_allclose(proto.joint_targets, tick.command.joint_targets, rtol=0, atol=0)
        np.testing.assert_array_equal(proto.swinging, tick.command.swinging)


def test_reading_a_few_topics_through_the_index_equals_reading_the_whole_file(ekf_run):
    _, _, path = ekf_run
    indexed, whole = read_recording(path, topics=REPLAY_TOPICS), read_recording(path)
    assert indexed.topics == whole.topics and indexed.metadata == whole.metadata
    assert indexed.attachments == whole.attachments and indexed.channel_metadata == whole.channel_metadata
    assert indexed.truncated is None and set(indexed.messages) == set(whole.messages)
    for topic, entries in indexed.messages.items():
        wanted = topic.startswith(schemas.SENSOR_PREFIX) or topic in REPLAY_TOPICS
        assert entries == (whole.messages[topic] if wanted else []), topic


def test_samples_decoded_field_by_field_equal_the_per_message_decoder(ekf_run):
    _, _, path = ekf_run
    recording = read_recording(path, topics=REPLAY_TOPICS)
    tagged = sorted((sequence, log_ns, codec.decode_sample(topic, data)) for topic in schemas.SENSOR_TOPICS
                    for log_ns, sequence, data in recording.messages.get(topic, []))
    read = recording.samples()
    assert len(read) == len(tagged)
    for sample, (_, _, expected) in zip(read, tagged):
        assert_same_sample(sample, expected)
