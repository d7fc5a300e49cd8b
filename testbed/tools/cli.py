"""`testbed` command line: run | export-urdf (more subcommands arrive with their issues).

Bad input gives one line on stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

from testbed.tools import interrupted_quietly  # first: a Ctrl-C during the imports below exits 130, quietly

interrupted_quietly.during_imports(__name__ == "__main__")

import argparse
import importlib
import os
import signal
import sys
import tomllib
from pathlib import Path
from typing import Any, Sequence

from datasets import commands as dataset_commands
from testbed.model.errors import ConfigError, PluginError, UserError
from testbed.model.registry import Registry
from testbed.runtime.interrupts import STOP_SIGNALS, held_interrupts, treat_stop_signals_as_interrupt
from testbed.runtime.outputs import prepare_output, write_atomically

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

# The subcommands defined in other modules, with their one-line help: a module is imported only
# when its subcommand is used, so that `--help` and bad input answer without loading the simulation.
SUBCOMMANDS = {
    "replay": ("datasets.commands", "feed a recorded run's sensor streams to an estimator and score it"),
    "info": ("datasets.commands", "duration, terrain, estimator, topics and metrics of a recorded run"),
    "view": ("datasets.commands", "convert a recorded run into a Rerun recording"),
    "export": ("datasets.export_commands", "convert a recorded run to ROS 2 MCAP, TUM trajectories or CSV tables"),
    "sweep": ("testbed.tools.sweep_cli",
              "a grid of runs (terrains x seeds x estimators x sensor presets): one MCAP per run and an index"),
    "profile": ("testbed.tools.profile", "time per simulated step of each stage of the run loop"),
    "bench": ("testbed.tools.bench_cli", "the estimator benchmarks: record walks, replay every estimator, report"),
    "locobench": ("testbed.tools.locobench_cli", "the locomotion benchmark: courses, gaits, contact models, long walks"),
}
# The named parts of a run, by option: (kind, entry point group). Names are listed and checked from
# the entry points alone (`Registry.check_spec` imports nothing), before the config loads the parts.
NAMED_PARTS = {"terrain": ("terrain", "terrains"), "contact": ("contact model", "contacts"),
               "gait": ("gait", "gaits"), "estimator": ("estimator", "estimators"),
               "controller": ("controller", "controllers")}
NO_ESTIMATOR = "none"


class OneLineParser(argparse.ArgumentParser):
    """argparse prints usage plus the error; we keep to one clear line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UserError(f"{self.prog}: {message}")


def _parse_assignment(text: str) -> dict[str, Any]:
    """`section.key=value` (value in TOML syntax) -> nested override dict."""
    if "=" not in text:
        raise UserError(f"--set expects section.key=value, got '{text}'")
    dotted, raw = text.split("=", 1)
    keys = dotted.strip().split(".")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    nested: dict[str, Any] = value
    for key in reversed(keys):
        nested = {key: nested}
    return nested


def _deep_update(target: dict[str, Any], update: dict[str, Any]) -> None:
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(target.get(key), dict):
            _deep_update(target[key], value)
        elif key in target and isinstance(value, dict) != isinstance(target[key], dict):
            raise UserError(f"'{key}' is given both as a value and as a section of values")
        else:
            target[key] = value


def _parse_target(text: str) -> list[float]:
    try:
        x, y = (float(part) for part in text.split(","))
    except ValueError:
        raise UserError(f"--target expects X,Y in metres, got '{text}'") from None
    return [x, y]


def _run_overrides(args: argparse.Namespace) -> dict[str, Any]:
    overrides: dict[str, Any] = {}
    for assignment in args.set or []:
        _deep_update(overrides, _parse_assignment(assignment))
    run = {name: getattr(args, name) for name in ("terrain", "contact", "gait", "estimator", "controller",
                                                  "duration", "seed") if getattr(args, name) is not None}
    gait = {name: getattr(args, name) for name in ("speed", "lateral_speed", "turn_rate")
            if getattr(args, name) is not None}
    if args.target is not None:
        gait["target"] = _parse_target(args.target)
    moving = args.target is not None or any(gait.get(name) for name in ("speed", "lateral_speed", "turn_rate"))
    if moving and "gait" not in run and "gait" not in overrides.get("run", {}) and args.config is None:
        run["gait"] = "tripod"      # a walking command without a gait walks the paper's tripod, not stand
    if run:
        _deep_update(overrides, {"run": run})
    if gait:
        _deep_update(overrides, {"gait": gait})
    if args.fault:
        _deep_update(overrides, {"sensors": {"faults": list(args.fault)}})
    return overrides


def choices(registry) -> str:
    """A registry's names for a help text, and the plugin form."""
    return " | ".join(registry.names()) + " | MODULE:CLASS"


def named_parts(option: str) -> Registry:
    """The registry of the part named by a run option, for its names only (nothing imported)."""
    kind, group = NAMED_PARTS[option]
    return Registry(kind, group, lambda obj: True, kind)


def _check_named_parts(args: argparse.Namespace) -> None:
    """Unknown part names given on the command line: PluginError before anything heavy loads."""
    for option in NAMED_PARTS:
        spec = getattr(args, option)
        if spec is not None and not (option == "estimator" and spec == NO_ESTIMATOR):
            named_parts(option).check_spec(spec)


def _add_run_parser(subparsers) -> None:
    parser = subparsers.add_parser("run", help="simulate one scenario")
    parser.add_argument("--terrain", help=f"{choices(named_parts('terrain'))}")
    parser.add_argument("--contact", help="compliant (hard finger) | dart (DART rigid contact)")
    parser.add_argument("--gait", help=f"{choices(named_parts('gait'))} (default stand; tripod with --target)")
    parser.add_argument("--speed", type=float, help="forward speed, m/s (cruise speed with --target)")
    parser.add_argument("--lateral-speed", type=float, help="speed to the left, m/s")
    parser.add_argument("--turn-rate", type=float, help="turning rate, rad/s counter-clockwise")
    parser.add_argument("--target", help="X,Y: walk to this point of the ground (m) and stop")
    parser.add_argument("--estimator", help=f"none | {choices(named_parts('estimator'))}")
    parser.add_argument("--controller", help=f"{choices(named_parts('controller'))} (none: gait and IK; posture: also keeps the "
                                              "body level and at height, needs an estimator)")
    parser.add_argument("--fault", action="append", metavar="SPEC",
                        help="inject a sensor fault, e.g. imu.accel.spike@5s (see docs/sensors.md; repeatable)")
    parser.add_argument("--duration", type=float, help="simulated seconds")
    parser.add_argument("--seed", type=int, help="seed of every random number of the run")
    parser.add_argument("--config", type=Path, help="TOML file overriding testbed/defaults.toml")
    parser.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE",
                        help="override one config value, e.g. terrain.slope_deg=-10 (repeatable)")
    parser.add_argument("--metrics", type=Path, help="write the run's metrics as JSON here")
    dataset_commands.add_run_arguments(parser)
    parser.set_defaults(handler=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    _check_named_parts(args)
    from testbed.model.kinematics import UnreachableTarget
    from testbed.runtime import config as config_module   # the simulation's imports, only for a run
    from testbed.runtime.metrics import write_metrics
    from testbed.runtime.runner import build_parts, run

    base = None if args.from_mcap is None else dataset_commands.config_from_mcap(args.from_mcap)
    cfg = config_module.load(args.config, _run_overrides(args), base=base)
    if args.metrics is not None:
        prepare_output(args.metrics, "--metrics", args.force)
    try:
        parts = build_parts(cfg)    # a plugin that cannot be found or built stops here, before any file
    except UnreachableTarget as error:
        raise ConfigError(f"the robot cannot take its start pose with this config ({error})") from None
    recorder = dataset_commands.recorder_for(args, cfg)
    outcome = run(cfg, recorder, parts=parts)
    path = getattr(recorder, "path", None)
    with held_interrupts():     # the run has stopped: a late Ctrl-C changes nothing of its files
        if args.metrics is not None:
            write_metrics(args.metrics, outcome.metrics)
    if not outcome.interrupted and path is not None:
        dataset_commands.after_run(args, path)
    with held_interrupts():
        return _report_run(cfg, outcome, path)


def _report_run(cfg, outcome, path: Path | None) -> int:
    print(_result_line(cfg, outcome.metrics, path))
    if outcome.note:
        print(f"testbed: note: {outcome.note}", file=sys.stderr)
    if outcome.interrupted:
        print(f"testbed: {outcome.error}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if outcome.error:
        print(f"testbed: {outcome.error}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _result_line(cfg, m: dict, path: Path | None) -> str:
    """The one line a run prints: what ran, its speed, whether it fell, where it was recorded."""
    support = m["weight_support_ratio"]
    compiled = f", plus {m['compile_s']:.1f} s compiling kernels" if m.get("compile_s") else ""
    return (f"{cfg.run.terrain}/{cfg.run.contact}/{cfg.run.gait}: {m['sim_time_s']:.2f} s simulated in "
            f"{m['wall_s']:.2f} s (x{m['realtime_factor']:.2f} real time{compiled}), fell={m['fell']}, "
            f"weight support {support if support is None else round(support, 4)}"
            + (f"; recorded {path}" if path is not None else "; not recorded"))


def _add_export_parser(subparsers) -> None:
    parser = subparsers.add_parser("export-urdf", help="write the robot's URDF")
    parser.add_argument("out", type=Path, help="output .urdf file")
    parser.add_argument("--config", type=Path, help="TOML file overriding testbed/defaults.toml")
    dataset_commands.add_force_argument(parser)
    parser.set_defaults(handler=_cmd_export_urdf)


def _cmd_export_urdf(args: argparse.Namespace) -> int:
    from testbed.model.robot import build_urdf
    from testbed.runtime import config as config_module

    cfg = config_module.load(args.config)
    prepare_output(args.out, "export-urdf", args.force)
    write_atomically(args.out, build_urdf(cfg.robot).encode("utf-8"))
    print(f"wrote {args.out}")
    return EXIT_OK


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand; only the module of the subcommand named in `argv` (all of
    them when `argv` is None) is imported, the others get their one-line help."""
    parser = OneLineParser(prog="testbed", description="Hexapod control and sensor-fusion testbed")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    _add_run_parser(subparsers)
    _add_export_parser(subparsers)
    chosen = _subcommand(argv)
    modules = dict.fromkeys(module for module, _ in SUBCOMMANDS.values())
    for module in modules:
        if argv is None or chosen in (name for name, (owner, _) in SUBCOMMANDS.items() if owner == module):
            importlib.import_module(module).add_subcommands(subparsers)
    for name, (_, help_text) in SUBCOMMANDS.items():
        if name not in subparsers.choices:
            subparsers.add_parser(name, help=help_text, add_help=False)
    return parser


def _subcommand(argv: Sequence[str] | None) -> str | None:
    """The subcommand `argv` names: its first word that is not an option."""
    return next((word for word in argv or () if not word.startswith("-")), None)


def main(argv: Sequence[str] | None = None) -> int:
    # A run started in the background by a non-interactive shell inherits SIGINT ignored; Ctrl-C,
    # `kill -INT`, SIGTERM and SIGHUP must still stop it cleanly (the recorder closes its file on the way out).
    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    treat_stop_signals_as_interrupt()
    try:
        return _main(argv)
    finally:
        for signum, handler in previous.items():
            # The command's work is done: a late Ctrl-C changes nothing. Called by a program: as it was.
            signal.signal(signum, signal.SIG_IGN if interrupted_quietly.is_command(__name__ == "__main__")
                          else handler if handler is not None else signal.SIG_DFL)


def _main(argv: Sequence[str] | None) -> int:
    try:
        argv = sys.argv[1:] if argv is None else argv
        args = build_parser(argv).parse_args(argv)
        return args.handler(args)
    except PluginError as error:
        print(f"testbed: {one_line(error)}", file=sys.stderr)
        return EXIT_USAGE
    except ConfigError as error:
        print(f"testbed: config error: {one_line(error)}", file=sys.stderr)
        return EXIT_USAGE
    except UserError as error:
        text = one_line(error)
        print(f"testbed: {text}" if not text.startswith("testbed") else text, file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("testbed: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader of our output went away (`testbed info run.mcap | head`): stop quietly.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILED
    except (RecursionError, MemoryError) as error:
        print(f"testbed: input too large or too deeply nested ({type(error).__name__})", file=sys.stderr)
        return EXIT_USAGE
    except OSError as error:        # datasets.writer.WriterFailed included
        print(f"testbed: {one_line(error)}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as error:      # a failure during the work: one line, never a traceback
        print(f"testbed: failed: {type(error).__name__}: {one_line(error)}", file=sys.stderr)
        return EXIT_FAILED


def one_line(error: BaseException | str) -> str:
    """An error's text on one line: control characters (a newline in a name) escaped."""
    text = str(error).strip() or type(error).__name__
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


if __name__ == "__main__":
    sys.exit(main())
