"""Nothing lost: truncated files are recovered, Ctrl-C cannot corrupt a file, a killed process
leaves a readable one; bad input is one clear UserError."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import textwrap

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from multiprocessing.connection import Connection

from datasets.reader import read_recording
from datasets.recorder import McapRecorder
from datasets.replay import replay
from tests.datasets.conftest import record, run_rerun
from tests.datasets.test_roundtrip import assert_same_sample
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
from testbed.model.errors import UserError


def cut(source, target, fraction: float) -> None:
    data = source.read_bytes()
    target.write_bytes(data[:int(len(data) * fraction)])


def test_a_truncated_file_gives_back_what_precedes_the_cut(ekf_run, tmp_path):
    _, ticks, path = ekf_run
    truncated = tmp_path / "cut.mcap"
    cut(path, truncated, 0.5)
    recording = read_recording(truncated)
    assert recording.truncated is not None and "truncated" in recording.truncation_note()
    written = [sample for tick in ticks for sample in tick.samples]
    read = recording.samples()
    assert 0 < len(read) < len(written)
    for a, b in zip(read, written):
        assert_same_sample(a, b)
    assert recording.metrics() is None and recording.config().run.estimator == "ekf"
    result = replay(truncated, "ekf")
    assert result.truncation_note is not None and result.samples == len(read)


def test_a_file_that_lost_only_its_summary_keeps_every_message(ekf_run, tmp_path):
    _, ticks, path = ekf_run
    data = path.read_bytes()
    # Footer: opcode, length, summary_start, summary_offset_start, crc, then the closing magic.
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 4 - 8 - 8)
    truncated = tmp_path / "no_summary.mcap"
    truncated.write_bytes(data[:summary_start])
    recording = read_recording(truncated)
    assert recording.truncated == "it is cut short before its footer"
    assert len(recording.samples()) == sum(len(tick.samples) for tick in ticks)
    assert recording.metrics() == {"roll_rmse_deg": 0.5}


def test_a_file_cut_inside_its_first_records_is_not_a_dataset(ekf_run, tmp_path):
    _, _, path = ekf_run
    truncated = tmp_path / "head.mcap"
    truncated.write_bytes(path.read_bytes()[:40])
    with pytest.raises(UserError, match="holds no testbed run config"):
        replay(truncated, "ekf")


def test_a_corrupt_chunk_ends_the_readable_part(ekf_run, tmp_path):
    _, _, path = ekf_run
    with path.open("rb") as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    chunk = chunks[len(chunks) // 2]
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2      # inside the chunk's compressed records
    data = bytearray(path.read_bytes())
    data[middle:middle + 64] = bytes(64)
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(bytes(data))
    recording = read_recording(corrupt)
    assert recording.truncated is not None and 0 < len(recording.samples())


def test_bad_files_are_one_line_user_errors(tmp_path):
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    cases = {tmp_path / "missing.mcap": "no such file", text: "not an MCAP file", empty: "not an MCAP file",
             tmp_path: "is a directory"}
    for path, message in cases.items():
        with pytest.raises(UserError, match=message) as error:
            replay(path, "ekf")
        assert "\n" not in str(error.value)


def test_a_foreign_mcap_is_not_a_testbed_dataset(tmp_path):
    path = tmp_path / "other.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("x", "jsonschema", b"{}")
        channel = writer.register_channel("/chatter", "json", schema)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    with pytest.raises(UserError, match="holds no testbed run config"):
        replay(path, "ekf")


def test_a_recording_without_the_streams_an_estimator_needs_is_refused(tmp_path):
    config = synthetic_config("complementary", sensors={"faults": ["imu.dropout@0s"]})
    path = tmp_path / "no_imu.mcap"
    record(path, config, list(generate_ticks(config, 0.3)))
    assert read_recording(path).topics["/sensors/encoders"].count > 0
    with pytest.raises(UserError, match="has no /sensors/imu messages, which a replay through 'ekf' needs"):
        replay(path, "ekf")


def test_an_unknown_estimator_is_a_user_error(ekf_run):
    _, _, path = ekf_run
    with pytest.raises(UserError, match="unknown estimator 'kalman'"):
        replay(path, "kalman")


@pytest.fixture
def ctrl_c_raises():
    """SIGINT raises KeyboardInterrupt, even where pytest was started with it ignored (in the background)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("ctrl_c_raises")
def test_ctrl_c_during_a_handover_is_delivered_after_it_and_the_file_closes_validly(tmp_path, monkeypatch):
    config = synthetic_config("complementary")
    ticks = list(generate_ticks(config, 1.2))
    recorder = McapRecorder(tmp_path / "run.mcap")
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    sent = []
    send = Connection.send

    def interrupt_then_send(connection, message):
        sent.append(message[0])
        if len(sent) == 1:
            os.kill(os.getpid(), signal.SIGINT)     # lands inside the handover at 0.5 s
        send(connection, message)
        sent.append("sent")

    monkeypatch.setattr(Connection, "send", interrupt_then_send)
    recorded = 0
    with pytest.raises(KeyboardInterrupt):
        for tick in ticks:
            recorded += 1
            recorder.record(tick)
    assert sent == ["write_ticks", "sent"]      # the handover went on to its end
    recorder.finish({"interrupted": True}, "interrupted")
    recording = read_recording(recorder.path)
    assert recording.truncated is None and recording.metrics() == {"interrupted": True}
    assert len(recording.samples()) == sum(len(tick.samples) for tick in ticks[:recorded])
    assert run_rerun("mcap", "check", str(recorder.path)).returncode == 0


# A child process recording 1.7 s of synthetic ticks to sys.argv[1], flushing at 0.5, 1.0 and 1.5 s.
RECORDING_RUN = textwrap.dedent("""
    import os, signal, sys
    from datasets.recorder import McapRecorder
    from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
    config = synthetic_config("complementary")
    recorder = McapRecorder(sys.argv[1])
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    for tick in generate_ticks(config, 1.7):
        recorder.record(tick)
""")

# The same, with a Ctrl-C to the whole process group (the writer process too) at 1.0 s.
INTERRUPTED_RUN = textwrap.dedent("""
    import os, signal, sys
    from datasets.recorder import McapRecorder
    from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
    config = synthetic_config("complementary")
    recorder = McapRecorder(sys.argv[1])
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    signal.signal(signal.SIGINT, signal.default_int_handler)    # also when started with SIGINT ignored
    try:
        for tick in generate_ticks(config, 1.7):
            recorder.record(tick)
            if tick.truth.t == 1.0:
                os.killpg(os.getpgid(0), signal.SIGINT)
    except KeyboardInterrupt:
        recorder.finish({"interrupted": True}, "interrupted")
        print("finished", recorder.path.exists())
""")


def run_child(script: str, path) -> subprocess.CompletedProcess:
    """Run `script` in its own process group; return when it and its writer process have ended
    (the writer holds the output pipes too)."""
    return subprocess.run([sys.executable, "-c", script, str(path)], cwd=os.getcwd(), timeout=120,
                          capture_output=True, text=True, start_new_session=True)


def test_ctrl_c_to_the_process_group_leaves_the_writer_running_and_the_file_complete(tmp_path):
    path = tmp_path / "interrupted.mcap"
    result = run_child(INTERRUPTED_RUN, path)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "finished True\n"      # `finish` returned after the rename
    recording = read_recording(path)
    assert recording.truncated is None and recording.metrics() == {"interrupted": True}
    assert recording.outcome()["error"] == "interrupted"
    assert 1.0 <= recording.duration_s() < 1.1
    assert run_rerun("mcap", "check", str(path)).returncode == 0


def assert_closed_by_the_writer_alone(path) -> None:
    """The writer closed the file validly, under its temporary name, with what was handed over."""
    partial = path.with_name(path.name + ".partial")
    assert partial.exists() and not path.exists()
    recording = read_recording(partial)
    assert recording.truncated is None and recording.metrics() == {}
    assert recording.outcome()["error"] == "the recording process ended without closing the file"
    assert 1.5 <= recording.duration_s() < 1.7
    assert run_rerun("mcap", "check", str(partial)).returncode == 0
    assert replay(partial, "complementary").metrics["roll_rmse_deg"] is not None


def test_a_killed_run_leaves_a_valid_partial_file_up_to_its_last_handover(tmp_path):
    path = tmp_path / "killed.mcap"
    result = run_child(RECORDING_RUN + "os.kill(os.getpid(), 9)\n", path)
    assert result.returncode == -9, result.stderr
    assert_closed_by_the_writer_alone(path)


def test_a_run_that_dies_of_an_exception_keeps_every_handed_over_message(tmp_path):
    path = tmp_path / "died.mcap"
    result = run_child(RECORDING_RUN + "raise RuntimeError('the run loop failed')\n", path)
    assert result.returncode == 1 and "the run loop failed" in result.stderr
    assert_closed_by_the_writer_alone(path)


# A child process whose writer may not grow the file much past its head (a full disk): the
# flush at 0.5 s fails in the writer, a later handover raises it, and so does `finish`.
FULL_DISK_RUN = textwrap.dedent("""
    import resource, sys
    from datasets.recorder import McapRecorder, WriterFailed
    from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf
    config = synthetic_config("complementary")
    recorder = McapRecorder(sys.argv[1])
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    limit = recorder.partial_path.stat().st_size + 20_000
    resource.prlimit(recorder.writer_pid, resource.RLIMIT_FSIZE, (limit, limit))
    try:
        for tick in generate_ticks(config, 1.7):
            recorder.record(tick)
    except WriterFailed as error:
        print("record:", tick.truth.t, error)
    try:
        recorder.finish({}, None)
    except WriterFailed as error:
        print("finish:", error)
""")


def test_a_failed_write_is_raised_in_one_line_and_leaves_the_partial_file(tmp_path):
    path = tmp_path / "full.mcap"
    result = run_child(FULL_DISK_RUN, path)
    assert result.returncode == 0, result.stderr
    record_line, finish_line = result.stdout.splitlines()
    partial = path.with_name(path.name + ".partial")
    assert record_line.startswith(("record: 1.0 ", "record: 1.5 "))
    assert record_line.endswith(f"writing {partial} failed: [Errno 27] File too large")
    assert finish_line.startswith(f"finish: writing {partial} failed: ") and "File too large" in finish_line
    assert partial.exists() and not path.exists()
    recording = read_recording(partial)
    assert recording.truncated is not None and recording.samples() == []
