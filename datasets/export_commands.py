"""`testbed export RUN.mcap --format ros2|tum|csv --out PATH` (datasets/export.py).

testbed/tools/cli.py imports this module only for `export`. Bad input raises UserError (one line
on stderr, exit code 2) before anything is written.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from testbed.model.errors import UserError

EXIT_OK, EXIT_FAILED = 0, 1
FORMATS = ("ros2", "tum", "csv")
OUTPUTS = {"ros2": "a .mcap file", "tum": "a folder (truth.tum, estimate.tum)", "csv": "a folder (one .csv per topic)"}


def add_subcommands(subparsers) -> None:
    parser = subparsers.add_parser(
        "export", help="convert a recorded run to ROS 2 MCAP, TUM trajectories or CSV tables")
    parser.add_argument("file", type=Path, metavar="RUN.mcap")
    parser.add_argument("--format", required=True, choices=FORMATS,
                        help="ros2: sensor_msgs/Imu, JointState, tf2_msgs/TFMessage, PoseStamped (ros2msg MCAP); "
                             "tum: truth.tum and estimate.tum for evo; csv: one table per topic")
    parser.add_argument("--out", type=Path, required=True, metavar="PATH",
                        help="; ".join(f"{name}: {what}" for name, what in OUTPUTS.items()))
    parser.set_defaults(handler=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    _check_out(args.format, args.out, args.file)
    from google.protobuf.message import DecodeError

    from datasets.dataset import Dataset
    from datasets.export import export

    dataset = Dataset(args.file)
    try:
        written = export(dataset, args.format, args.out)
    except (DecodeError, KeyError, ValueError, OSError) as error:
        print(f"testbed: cannot export {args.file} as {args.format}: {type(error).__name__}: {error}", file=sys.stderr)
        return EXIT_FAILED
    print(f"wrote {args.out}" if args.format == "ros2" else f"wrote {len(written)} files to {args.out}")
    return EXIT_OK


def _check_out(format: str, out: Path, source: Path) -> None:
    if not source.is_file():
        raise UserError(f"{source}: no such file")
    if format == "ros2":
        if out.is_dir():
            raise UserError(f"--out {out} is a folder: --format ros2 writes {OUTPUTS['ros2']}")
        if out.exists() and out.resolve() == source.resolve():
            raise UserError(f"--out {out} would overwrite the file being exported")
    elif out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file: --format {format} writes {OUTPUTS[format]}")
    parent = out.parent if format == "ros2" else out
    while not parent.exists():
        parent = parent.parent
    if not os.access(parent, os.W_OK):
        raise UserError(f"--out {out}: folder {parent} is not writable")
