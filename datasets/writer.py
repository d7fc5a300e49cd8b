"""The MCAP file of a run: `DatasetWriter` writes it in the calling process, `WriterProcess`
has a forked process write it.

`WriterProcess` takes the serialising (protobuf, from the columns of `codec.TickColumns`) and
the file writing (mcap's `add_message`, zstd compression, indexes, the final rename) off the run
loop, which holds the GIL for the whole simulated step: a thread would only take turns with it,
a process runs beside it.

- Batches of ticks (`write_ticks`, as columns) or of serialised messages (`write`) go to the
  writer through a `multiprocessing` Pipe, one pickle per handover, into a kernel buffer large
  enough for a whole batch (`Link`), so that handing it over is a copy and does not wait for the
  writer to be scheduled; the writer answers only the start and `close`, and reports a failed
  write at once, which the next handover or `close` raises as `WriterFailed`.
- The writer is scheduled as a batch process (SCHED_BATCH): a handover wakes it without having
  it preempt the recording process, which would then wait for the handover's end.
- The writer keeps off the CPU that the recording process runs on (`keep_off_cpu`, at each
  handover) where the recording process may use another: Linux wakes a process on the CPU of the
  one that woke it, so with the other CPUs busy (a second program on a 2-core machine) the writer
  would take its time from the run loop's CPU (the loop then waits for it about a fifth of its time).
- The writer ignores SIGINT and SIGTERM (Ctrl-C reaches the whole foreground process group) and
  stops on `close`, or when its pipe reaches end of file because the recording process ended
  without closing: it then closes the file validly and leaves it under its `.partial` name.
- It is started with `os.fork`: it needs nothing but what this module imported (mcap, zstd,
  protobuf and the codec, file I/O) and the classes of a sensor plugin's samples (imported
  already, or by name on unpickling), so forking copies no state it could trip on (it never
  touches the parent's threads, BLAS or DART), costs a few milliseconds, and works in daemonic
  processes (Dask nanny workers, `multiprocessing.Pool` workers), where `multiprocessing.Process`
  refuses to start children.
"""

from __future__ import annotations

import fcntl
import gc
import json
import math
import os
import platform
import signal
import time
from functools import cache
from importlib import metadata as package_metadata
from multiprocessing import Pipe
from multiprocessing.connection import Connection
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from datasets import codec, heightmap_store, schemas
from datasets.signals import sigint_deferred

if TYPE_CHECKING:
    from testbed.runtime.config import Config

PARTIAL_SUFFIX = ".partial"
CHUNK_SIZE = 8 * 2**20      # bytes; chunks normally close at each flush, before reaching this
PROFILE = "hexapod-testbed"
VERSIONED_PACKAGES = ("hexapod-testbed", "numpy", "scipy", "dartpy", "filterpy", "control", "AHRS", "vqf",
                      "mcap", "mcap-protobuf-support", "foxglove-schemas-protobuf", "protobuf", "rerun-sdk")
PIPE_BYTES = 2**20          # kernel buffer of the pipe to the writer (Linux's default upper limit)
ENDED_OUTCOME = {"error": "the recording process ended without closing the file"}

Message = tuple[int, int, bytes, int]       # channel id, log time (ns, also the publish time), data, sequence


class WriterFailed(OSError):
    """A write to the dataset failed; the file was left as it was then."""


class OutputBusy(WriterFailed):
    """Another process is writing the same file."""


def partial_path_of(path: Path) -> Path:
    return path.with_name(path.name + PARTIAL_SUFFIX)


def open_partial(path: Path) -> IO[bytes]:
    """`path`'s temporary file, created or emptied, opened for writing and locked (flock) for as
    long as any process holds it open: a second process writing to the same path stops here with
    OutputBusy instead of emptying the first one's file."""
    partial = partial_path_of(path)
    while True:
        descriptor = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(descriptor)
            raise OutputBusy(f"{path} is being written by another process (its {partial.name} is locked)") from None
        try:
            same = os.path.samestat(os.fstat(descriptor), os.stat(partial))
        except FileNotFoundError:       # renamed away meanwhile by the process that held it
            same = False
        if same:
            os.ftruncate(descriptor, 0)
            return os.fdopen(descriptor, "wb")
        os.close(descriptor)


def publish(partial: Path, path: Path, replace: bool) -> None:
    """Give the finished temporary file its final name; unless `replace`, only if that name is free
    (else OutputBusy, and the file keeps its temporary name)."""
    if replace:
        os.replace(partial, path)
        return
    try:
        os.link(partial, path)
    except FileExistsError:
        raise OutputBusy(f"{path} was created by another process meanwhile: this run is kept as {partial}") from None
    os.unlink(partial)


class DatasetWriter:
    """An MCAP file of the dataset format: every topic registered, the run description first,
    written under a temporary name until `close`."""

    def __init__(self, path: str | Path, stream: IO[bytes] | None = None, replace: bool = True):
        """Write to `stream` if given (the temporary file, opened), else create the temporary file;
        `replace`: the final name may replace an existing file."""
        self.path = Path(path)
        self.partial_path = partial_path_of(self.path)
        self.replace = replace
        if stream is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            stream = open_partial(self.path)
        self._file = stream
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._failure: BaseException | None = None
        self._encoder = codec.Encoder()
        self.closed = False
        self._writing(self._writer.start, profile=PROFILE, library=f"hexapod-testbed/{_version('hexapod-testbed')}")
        self.channels = {topic.name: self._register(topic) for topic in schemas.TOPICS}

    def describe_run(self, run_info: dict[str, str], config: "Config", urdf: str) -> None:
        """Metadata and attachments go before any message, so that even a truncated file can be
        replayed."""
        self.describe(RunDescription.of(run_info, config, urdf))

    def describe(self, description: "RunDescription") -> None:
        self._writing(self._describe_run, description)

    def write(self, messages: list[Message], flush: bool) -> None:
        """Add the messages; `flush` closes the chunk and puts it on the file, flushed."""
        self._writing(self._write, messages, flush)

    def write_ticks(self, ticks: codec.TickColumns, flush: bool) -> None:
        """Serialise the ticks' messages (`codec.Encoder.messages`) and add them, as `write`; a
        sensor plugin's sample topic is registered when first seen."""
        self._writing(self._write_ticks, ticks, flush)

    def close(self, metrics: dict, outcome: dict[str, str], rename: bool = True) -> None:
        """Write the metrics, the outcome and the summary, then give the file its final name
        (unless not `rename`). If a write fails, now or before (`WriterFailed`), close the file as
        it is under its temporary name and raise."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writing(self._finish, metrics, outcome)
            self._file.flush()
            if rename:      # before closing: the lock keeps another writer of the same path out until then
                publish(self.partial_path, self.path, self.replace)
            self._file.close()
        finally:
            if not self._file.closed:
                self._close_quietly()

    def abandon(self) -> None:
        """Close without a summary and delete the temporary file (nothing worth keeping was written)."""
        self.closed = True
        self._close_quietly()
        self.partial_path.unlink(missing_ok=True)

    def _close_quietly(self) -> None:
        """Close the file after an error, which already says what went wrong."""
        try:
            self._file.close()
        except OSError:
            pass

    def _writing(self, write, *args, **kwargs) -> None:
        """Run one write, safe from Ctrl-C; the first error stops every later write."""
        if self._failure is not None:
            raise WriterFailed(f"an earlier write failed ({self._failure})") from self._failure
        with sigint_deferred():
            try:
                write(*args, **kwargs)
            except Exception as error:
                self._failure = error
                raise

    def _describe_run(self, description: "RunDescription") -> None:
        writer = self._writer
        writer.add_metadata("run", {"format_version": schemas.FORMAT_VERSION, **description.run_info})
        writer.add_metadata("config", {"json": description.config_json})
        writer.add_metadata("versions", description.versions)
        created = time.time_ns()
        writer.add_attachment(created, 0, "config.toml", "application/toml", description.config_toml.encode())
        writer.add_attachment(created, 0, "robot.urdf", "application/xml", description.urdf.encode())
        for name, (media_type, data) in description.attachments.items():
            writer.add_attachment(created, 0, name, media_type, data)
        if description.urdf:
            self._encoder.describe_robot(description.urdf)

    def _write(self, messages: list[Message], flush: bool) -> None:
        add = self._writer.add_message
        for channel, log_ns, data, sequence in messages:
            add(channel, log_ns, data, log_ns, sequence)
        if flush:
            self._writer.flush()

    def _write_ticks(self, ticks: codec.TickColumns, flush: bool) -> None:
        add, channels = self._writer.add_message, self.channels
        for topic, log_ns, data, sequence in self._encoder.messages(ticks):
            channel = channels.get(topic.name)
            if channel is None:
                channel = channels[topic.name] = self._register(topic)
            add(channel, log_ns, data, log_ns, sequence)
        if flush:
            self._writer.flush()

    def _finish(self, metrics: dict, outcome: dict[str, str]) -> None:
        self._writer.add_metadata("metrics", {"json": json.dumps(_json_safe(metrics), sort_keys=True)})
        self._writer.add_metadata("outcome", outcome)
        self._writer.finish()

    def _register(self, topic: schemas.Topic) -> int:
        descriptor_set = build_file_descriptor_set(topic.message_class).SerializeToString()
        schema_id = self._writer.register_schema(topic.message_class.DESCRIPTOR.full_name, SchemaEncoding.Protobuf,
                                                 descriptor_set)
        metadata = {"sample_class": topic.sample_class} if topic.sample_class else {}
        return self._writer.register_channel(topic.name, MessageEncoding.Protobuf, schema_id, metadata)


class RunDescription:
    """What `describe_run` writes, in plain strings (it crosses to the writer process)."""

    def __init__(self, run_info: dict[str, str], config_json: str, config_toml: str, urdf: str,
                 versions: dict[str, str], attachments: dict[str, tuple[str, bytes]] | None = None):
        self.run_info, self.config_json, self.config_toml, self.urdf = run_info, config_json, config_toml, urdf
        self.versions = versions
        self.attachments = attachments or {}    # more files the run needs: name -> (media type, data)

    @classmethod
    def of(cls, run_info: dict[str, str], config: "Config", urdf: str) -> "RunDescription":
        return cls(run_info, json.dumps(config.to_dict(), sort_keys=True), config.to_toml(), urdf, package_versions(),
                   heightmap_store.attachments_of(config))


class Link:
    """One end of the two one-way pipes between the recording process and its writer."""

    def __init__(self, incoming: Connection, outgoing: Connection):
        self.incoming, self.outgoing = incoming, outgoing

    def send(self, message: tuple) -> None:
        self.outgoing.send(message)

    def recv(self) -> tuple:
        return self.incoming.recv()

    def poll(self) -> bool:
        return self.incoming.poll()

    def close(self) -> None:
        self.incoming.close()
        self.outgoing.close()


def link_pair() -> tuple[Link, Link]:
    """(recording process's end, writer's end); the pipe to the writer holds `PIPE_BYTES` where
    the system allows it, else its default (64 kB)."""
    command_reader, command_writer = Pipe(duplex=False)
    reply_reader, reply_writer = Pipe(duplex=False)
    try:
        fcntl.fcntl(command_writer.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except OSError:         # above /proc/sys/fs/pipe-max-size, or the user's pipe quota
        pass
    return Link(reply_reader, command_writer), Link(command_reader, reply_writer)


class WriterProcess:
    """A `DatasetWriter` in a forked process, fed through a pipe: `write` hands a batch over and
    returns, `close` returns when the file is closed and renamed."""

    def __init__(self, path: str | Path, run_info: dict[str, str], config: "Config", urdf: str,
                 replace: bool = True):
        """Create the temporary file (its errors are raised here), fork the writer, have it write
        the file's head and the run description, and wait until it has."""
        self.path = Path(path)
        self.partial_path = partial_path_of(self.path)
        self.closed = False
        self._kept_off: int | None = None      # the CPU the writer keeps off (`keep_off_cpu`)
        description = RunDescription.of(run_info, config, urdf)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        stream = open_partial(self.path)
        self._connection, writer_end = link_pair()
        try:
            self.pid = _fork_writer(self.path, stream, description, writer_end, self._connection, replace)
        finally:
            writer_end.close()
            stream.close()          # nothing was written to it here: the writer has its own copy
        try:
            self.channels: dict[str, int] = self._reply("ready")
        except WriterFailed:
            self._stop_waiting()
            if self.partial_path.exists() and not self.partial_path.stat().st_size:
                self.partial_path.unlink()
            raise

    def keep_off_cpu(self, cpu: int | None) -> None:
        """Have the writer run on the CPUs this process may use other than `cpu` (the one it runs
        on: `running_cpu`), when there are such; as it was with none or `cpu` None."""
        if cpu is None or cpu == self._kept_off:
            return
        others = os.sched_getaffinity(0) - {cpu}
        try:
            if others:
                os.sched_setaffinity(self.pid, others)
                self._kept_off = cpu
        except OSError:         # the writer has ended: the next handover says why
            pass

    def write(self, messages: list[Message], flush: bool) -> None:
        """Hand the messages over; raise `WriterFailed` if an earlier batch failed."""
        self._raise_reported_failure()
        self._send("write", messages, flush)

    def write_ticks(self, ticks: codec.TickColumns, flush: bool) -> None:
        """Hand the ticks over, to be serialised by the writer; raise `WriterFailed` if an earlier
        batch failed."""
        self._raise_reported_failure()
        self._send("write_ticks", ticks, flush)

    def close(self, metrics: dict, outcome: dict[str, str]) -> None:
        """Have the writer write the metrics, outcome and summary and rename the file; wait for it."""
        if self.closed:
            return
        self.closed = True
        try:
            self._send("close", _json_safe(metrics), outcome)
            self._reply("closed")
        finally:
            self._stop_waiting()

    def _stop_waiting(self) -> None:
        """Close the pipe (the writer, if still running, closes the file) and wait for the writer."""
        self._connection.close()
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:       # reaped already, where SIGCHLD is ignored
            pass

    def _send(self, command: str, *args) -> None:
        try:
            with sigint_deferred():     # a message cut short would leave the writer's stream unreadable
                self._connection.send((command, *args))
        except (BrokenPipeError, ConnectionResetError):
            self._raise_reported_failure()
            raise WriterFailed(self._failure_text("the writer process ended")) from None

    def _raise_reported_failure(self) -> None:
        if self._connection.poll():
            self._reply("no reply")

    def _reply(self, expected: str):
        """The writer's answer, if it is `expected`; `WriterFailed` if it reports a failure or ended."""
        try:
            kind, content = self._connection.recv()
        except EOFError:
            raise WriterFailed(self._failure_text("the writer process ended")) from None
        if kind == "failed":
            raise WriterFailed(self._failure_text(content))
        assert kind == expected, (kind, expected)
        return content

    def _failure_text(self, reason: str) -> str:
        return f"writing {self.partial_path} failed: {reason}"


# /proc/<pid>/stat: the CPU last run on is field 39, the 37th after the command's name ("(...)")
PROCESSOR_FIELD = 36


def running_cpu() -> int | None:
    """The CPU the calling thread runs on (Linux's /proc), None where that is not known. (psutil's
    `Process().cpu_num()` reads the same field; psutil is only a test dependency here.)"""
    try:
        with open("/proc/thread-self/stat", "rb") as stat:
            return int(stat.read().rsplit(b")", 1)[1].split()[PROCESSOR_FIELD])
    except (OSError, ValueError, IndexError):
        return None


def _fork_writer(path: Path, stream: IO[bytes], description: RunDescription, connection: Link,
                 parent_end: Link, replace: bool) -> int:
    """Fork the writer process with SIGINT, SIGTERM and SIGHUP ignored from its first instruction on."""
    stopping = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, stopping)
    try:
        pid = os.fork()
        if pid == 0:
            for signum in stopping:
                signal.signal(signum, signal.SIG_IGN)
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
            parent_end.close()
            _run_writer(path, stream, description, connection, replace)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
    return pid


def _run_writer(path: Path, stream: IO[bytes], description: RunDescription, connection: Link,
                replace: bool) -> None:
    """The writer process's life; it leaves through `os._exit` (no handlers of the parent run)."""
    gc.disable()        # its messages make no reference cycles; collecting would copy the parent's pages
    _yield_to_the_run_loop()
    status = 1
    try:
        _serve(path, stream, description, connection, replace)
        status = 0
    finally:
        os._exit(status)


def _yield_to_the_run_loop() -> None:
    """Schedule the writer as a batch process (Linux's SCHED_BATCH, same share of the CPU): a
    handover that wakes it then does not make it preempt the recording process mid-handover."""
    try:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError):       # not Linux
        pass


def _serve(path: Path, stream: IO[bytes], description: RunDescription, connection: Link,
           replace: bool) -> None:
    try:
        dataset = DatasetWriter(path, stream, replace)
        dataset.describe(description)
    except Exception as error:
        _tell(connection, ("failed", _one_line(error)))
        return
    try:
        connection.send(("ready", dataset.channels))
    except OSError:         # the recording process ended meanwhile (a Ctrl-C): keep a valid file
        dataset.close({}, ENDED_OUTCOME, rename=False)
        return
    _write_batches(dataset, connection)


def _write_batches(dataset: DatasetWriter, connection: Link) -> None:
    """Write what comes until `close` or the end of the pipe; report the first failed write."""
    reported = False
    writes = {"write": dataset.write, "write_ticks": dataset.write_ticks}
    while True:
        try:
            command, *args = connection.recv()
        except EOFError:
            dataset.close({}, ENDED_OUTCOME, rename=False)
            return
        if command == "close":
            _close(dataset, args, connection)
            return
        try:
            writes[command](*args)
        except Exception as error:
            if not reported:
                _tell(connection, ("failed", _one_line(error)))
                reported = True


def _close(dataset: DatasetWriter, args: list, connection: Link) -> None:
    try:
        dataset.close(*args)
    except Exception as error:
        _tell(connection, ("failed", _one_line(error)))
    else:
        _tell(connection, ("closed", None))


def _tell(connection: Link, message: tuple) -> None:
    """Answer the recording process, if it is still there to listen."""
    try:
        connection.send(message)
    except OSError:
        pass


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _json_safe(value):
    """Metrics as strict JSON: numpy scalars to Python, non-finite floats to null."""
    if isinstance(value, dict):
        return {str(key): _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@cache
def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    for name in VERSIONED_PACKAGES:
        versions[name] = _version(name)
    return versions


@cache
def _version(name: str) -> str:
    try:
        return package_metadata.version(name)
    except package_metadata.PackageNotFoundError:
        return "not installed"
