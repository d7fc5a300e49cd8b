"""The dataset side of the `testbed` command line: `replay`, `info`, `view`, and the recording
options of `run` (`--out`, `--rerun`, `--spawn`, `--from`).

testbed/cli.py owns the parser and `main`; it calls `add_subcommands` and `add_run_arguments`
while building the parser, `config_from_mcap` for `run --from`, `recorder_for` before a run and
`after_run` after it. Handlers return an exit code; bad input raises UserError (one line, exit 2).
"""

from __future__ import annotations

import argparse
import itertools
import os
import struct
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from datasets.progress import show_progress
from testbed.model.errors import UserError
from testbed.runtime.outputs import prepare_output
from testbed.model.registry import file_stem

if TYPE_CHECKING:       # the recording side is imported by the handlers that use it: `--help` stays fast
    from testbed.runtime.config import Config
    from testbed.runtime.recording import Recorder

EXIT_OK = 0
RUNS_FOLDER = Path("runs")
NO_RECORDING = "none"       # --out none
LIVE_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


# --- run -------------------------------------------------------------------------------------

def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, metavar="RUN.mcap",
                        help="record the run here (default runs/<UTC time>_<terrain>_<estimator>.mcap; "
                             "'none': do not record)")
    parser.add_argument("--no-record", action="store_true", help="run without writing an MCAP file (as --out none)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar (there is none when stderr is not a terminal)")
    parser.add_argument("--rerun", type=Path, metavar="RUN.rrd", help="also write a Rerun recording of the run")
    parser.add_argument("--spawn", action="store_true", help="open the Rerun viewer on the run when it ends")
    parser.add_argument("--rerun-live", action="store_true",
                        help="stream the run to a Rerun viewer while it runs (spawned, or --rerun-connect's)")
    parser.add_argument("--rerun-connect", metavar="URL",
                        help="with --rerun-live: the viewer's address, e.g. rerun+http://127.0.0.1:9876/proxy")
    parser.add_argument("--from", dest="from_mcap", type=Path, metavar="RUN.mcap",
                        help="start from the config recorded in RUN.mcap (other options override it)")
    add_force_argument(parser)


def add_force_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--force", action="store_true", help="replace output files that exist already")


def config_from_mcap(path: str | Path) -> dict[str, Any]:
    """The resolved config recorded in a run's file, as a plain dict (`testbed.runtime.config.from_dict`)."""
    from datasets.reader import read_description

    with damaged_file_errors(Path(path)):
        return read_description(path).config_dict()


def records(args: argparse.Namespace) -> bool:
    """Whether `testbed run` writes an MCAP file: not with --no-record or --out none."""
    return not args.no_record and (args.out is None or str(args.out) != NO_RECORDING)


def recorder_for(args: argparse.Namespace, config: "Config") -> "Recorder":
    """The recorder of a `testbed run`: to --out (the output rule: `prepare_output`), or to the
    default path under runs/; with --no-record (or --out none) a NullRecorder; with a progress bar
    on a terminal unless --quiet."""
    from datasets.progress import ProgressRecorder
    from datasets.recorder import McapRecorder
    from testbed.runtime.recording import NullRecorder

    if not records(args) and (args.rerun is not None or args.spawn):
        raise UserError("--rerun and --spawn convert the recorded file: they need a recording (drop --no-record)")
    recorder: "Recorder" = NullRecorder()
    _check_live(args)
    if records(args):
        force = getattr(args, "force", False)
        if args.rerun is not None:
            prepare_output(args.rerun, "--rerun", force)
        recorder = McapRecorder(default_run_path(config)) if args.out is None else \
            McapRecorder(prepare_output(args.out, "--out", force), replace=force)
    if args.rerun_live:
        from datasets.rerun_export import LiveRerun

        recorder = LiveRerun(recorder, args.rerun_connect)
    return ProgressRecorder(recorder) if show_progress(args.quiet) else recorder


def _check_live(args: argparse.Namespace) -> None:
    if args.rerun_connect is not None and not args.rerun_live:
        raise UserError("--rerun-connect goes with --rerun-live")
    if args.rerun_connect is not None and not args.rerun_connect.startswith(LIVE_SCHEMES):
        raise UserError(f"--rerun-connect expects rerun+http://HOST:PORT/proxy, got '{args.rerun_connect}'")
    if args.rerun_live and args.rerun_connect is None and not _has_display():
        raise UserError("--rerun-live: no display to open a viewer on; start one elsewhere (`rerun`) and give "
                        "--rerun-connect rerun+http://HOST:9876/proxy")


def after_run(args: argparse.Namespace, mcap_path: str | Path) -> None:
    """Write the Rerun recording of the finished run (--rerun) and open a viewer on it (--spawn)."""
    if args.rerun is None and not args.spawn:
        return
    rrd = args.rerun if args.rerun is not None else Path(mcap_path).with_suffix(".rrd")
    _export(mcap_path, rrd)
    if args.spawn:
        spawn_viewer(rrd)


def default_run_path(config: "Config", folder: Path = RUNS_FOLDER) -> Path:
    """A new `runs/<UTC time>_<terrain>_<estimator>[-N].mcap`. The name is reserved by creating its
    `.partial` file exclusively: runs started in parallel in the same second (a sweep) would
    otherwise pick the same name and rename each other's files away."""
    from datasets.recorder import PARTIAL_SUFFIX

    folder.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    stem = f"{stamp}_{file_stem(config.run.terrain)}_{file_stem(config.run.estimator)}"
    for n in itertools.count(1):
        path = folder / (f"{stem}.mcap" if n == 1 else f"{stem}-{n}.mcap")
        if path.exists():
            continue
        try:
            os.close(os.open(path.with_name(path.name + PARTIAL_SUFFIX), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue
        return path


# --- replay, info, view ----------------------------------------------------------------------

def add_subcommands(subparsers) -> None:
    replay = subparsers.add_parser("replay", help="feed a recorded run's sensor streams to an estimator and score it")
    replay.add_argument("file", type=Path, metavar="RUN.mcap")
    replay.add_argument("--estimator", required=True, help="ekf | ukf | complementary | madgwick | mahony | vqf")
    replay.add_argument("--out", type=Path, metavar="OUT.mcap", help="write the run with the replayed estimates")
    replay.add_argument("--metrics", type=Path, metavar="FILE.json", help="write the replay's metrics as JSON")
    replay.add_argument("--quiet", action="store_true", help="no progress bar (there is none when stderr is not a terminal)")
    add_force_argument(replay)
    replay.set_defaults(handler=cmd_replay)

    info = subparsers.add_parser("info", help="duration, terrain, estimator, topics and metrics of a recorded run")
    info.add_argument("file", type=Path, metavar="RUN.mcap")
    info.set_defaults(handler=cmd_info)

    view = subparsers.add_parser("view", help="convert a recorded run into a Rerun recording")
    view.add_argument("file", type=Path, metavar="RUN.mcap")
    view.add_argument("--rrd", type=Path, metavar="RUN.rrd", help="output file (default: RUN.rrd beside RUN.mcap)")
    view.add_argument("--spawn", action="store_true", help="open the Rerun viewer on it")
    add_force_argument(view)
    view.set_defaults(handler=cmd_view)


@contextmanager
def damaged_file_errors(path: Path) -> Iterator[None]:
    """A recorded message or array that does not decode, or does not fit what the testbed records,
    as a one-line UserError (exit 2): the file is damaged or foreign."""
    from google.protobuf.message import DecodeError

    try:
        yield
    except (DecodeError, ValueError, IndexError, KeyError, TypeError, OverflowError, struct.error) as error:
        text = " ".join(str(error).split())[:200]
        raise UserError(f"{path}: damaged or foreign data ({type(error).__name__}: {text})") from None


def cmd_replay(args: argparse.Namespace) -> int:
    from datasets.progress import with_progress
    from datasets.replay import replay
    from testbed.runtime.metrics import write_metrics

    if args.estimator == "none":
        raise UserError("replay needs an estimator to feed: --estimator none has nothing to replay")
    if args.metrics is not None:
        prepare_output(args.metrics, "--metrics", args.force)
    if args.out is not None:
        if args.out.resolve() == args.file.resolve():
            raise UserError(f"--out {args.out} would overwrite the file being replayed")
        prepare_output(args.out, "--out", args.force)
    with damaged_file_errors(args.file):
        result = replay(args.file, args.estimator, args.out, with_progress if show_progress(args.quiet) else None)
    if result.truncation_note:
        print(f"testbed: warning: {result.truncation_note}", file=sys.stderr)
    if args.metrics is not None:
        write_metrics(args.metrics, result.metrics)
    m = result.metrics
    print(f"replay of {args.file} through {args.estimator}: roll RMSE {_deg(m['roll_rmse_deg'])}, "
          f"pitch RMSE {_deg(m['pitch_rmse_deg'])}; {m['sim_time_s']:.2f} s of data, {result.samples} samples, "
          f"in {m['wall_s']:.2f} s (x{m['realtime_factor']:.1f} real time)"
          + (f"; wrote {args.out}" if args.out is not None else ""))
    return EXIT_OK


def cmd_info(args: argparse.Namespace) -> int:
    from datasets.info import describe

    with damaged_file_errors(args.file):
        text = describe(args.file)
    print(text)
    return EXIT_OK


def cmd_view(args: argparse.Namespace) -> int:
    rrd = args.rrd if args.rrd is not None else args.file.with_suffix(".rrd")
    prepare_output(rrd, "--rrd", args.force)
    with damaged_file_errors(args.file):
        _export(args.file, rrd)
    if args.spawn:
        spawn_viewer(rrd)
    return EXIT_OK


# --- helpers ---------------------------------------------------------------------------------

def _export(mcap_path: str | Path, rrd: Path) -> None:
    from datasets.reader import read_recording
    from datasets.rerun_export import export_rrd

    recording = read_recording(mcap_path)
    if not recording.message_count():
        raise UserError(f"{mcap_path} holds no messages to view" + (f" ({recording.truncated})" if recording.truncated else ""))
    if recording.truncation_note():
        print(f"testbed: warning: {recording.truncation_note()}", file=sys.stderr)
    try:
        export_rrd(recording, rrd)
    except RuntimeError as error:       # the Rerun SDK's failures to write (a full disk)
        raise OSError(f"writing {rrd} failed: {' '.join(str(error).split())}") from None
    print(f"wrote {rrd}")


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def spawn_viewer(rrd: Path) -> None:
    """Open the Rerun viewer on `rrd` in the background, when there is a display to open it on."""
    if not _has_display():
        print(f"testbed: no display: not opening a viewer (run `rerun {rrd}` where there is one)", file=sys.stderr)
        return
    subprocess.Popen([sys.executable, "-m", "rerun", str(rrd)], start_new_session=True,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _deg(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4f} deg"
