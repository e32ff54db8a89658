"""The ``uav-depth`` command line.

Subcommands sit in one name -> module table (:data:`COMMANDS`). Each module has
``configure(parser)`` and ``run(args) -> int`` and imports heavy or optional
dependencies only inside ``run``, so ``--help`` always works. Library code raises;
this module alone maps errors to one line on stderr and an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from uav_depth.cli.exit_codes import EXIT_CANTCREAT, EXIT_CONFIG, EXIT_ERROR, EXIT_INTERRUPTED
from uav_depth.cli.signals import SIGNALS
from uav_depth.core.errors import CalibrationError, ConfigError, DependencyError, OutputExistsError, UavDepthError

#: Subcommands that run the daemon: their signal handlers go in before anything else is imported.
DAEMONS = ("run", "sitl")

#: name -> (module, one-line help).
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("uav_depth.cli.commands.demo", "synthesise a session and evaluate the pipeline on it (no hardware)"),
    "synth": ("uav_depth.cli.commands.synth", "write a synthetic stereo session with exact reference disparity"),
    "disparity": ("uav_depth.cli.commands.disparity", "compute the disparity of one stereo pair"),
    "evaluate": ("uav_depth.cli.commands.evaluate", "score the pipeline against reference disparity in a log"),
    "tune": ("uav_depth.cli.commands.tune", "search SGBM+WLS parameters on a log (the paper's GA and better)"),
    "params": ("uav_depth.cli.commands.params", "print the default parameter file or check one"),
    "bench": ("uav_depth.cli.commands.bench",
              "time the daemon pipeline against OpenCV's sample pipeline on synthetic scenes (prints figures)"),
    "run": ("uav_depth.cli.commands.run", "the on-board daemon: stereo -> branch distance -> MAVLink DISTANCE_SENSOR"),
    "sitl": ("uav_depth.cli.commands.sitl",
             "fly the daemon against a simulated autopilot: synthetic stereo rendered from its pose"),
    "autopilot-params": ("uav_depth.cli.commands.autopilot_params",
                         "print the autopilot's settings (ArduPilot or PX4) that fit the range the daemon sends"),
    "session": ("uav_depth.cli.commands.session", "make a session (log layout) from a folder of stereo pairs"),
    "check-rig": ("uav_depth.cli.commands.check_rig",
                  "measure the stereo rig's vertical misalignment (is it still rectified? can SGBM work?)"),
    "sources": ("uav_depth.cli.commands.sources", "list the frame sources run accepts (and probe for hardware)"),
    "reference": ("uav_depth.cli.commands.reference",
                  "give logged frames a reference disparity (import one, or run an ONNX stereo network)"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole parser; with ``only``, just that subcommand's module is imported and configured
    (``uav-depth run`` need not import the tuner to parse its arguments)."""
    from uav_depth.core import __version__

    parser = argparse.ArgumentParser(
        prog="uav-depth", description="Stereo branch ranging for pruning drones: SGBM+WLS, a GA tuner, MAVLink output.")
    parser.add_argument("--version", action="version", version=f"uav-depth {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if only is None or name == only:
            importlib.import_module(module).configure(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    command = next((w for w in words if not w.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except KeyboardInterrupt:
        print("uav-depth: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ConfigError, CalibrationError) as exc:
        print(f"uav-depth {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except DependencyError as exc:
        print(f"uav-depth {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except OutputExistsError as exc:
        print(f"uav-depth {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_CANTCREAT
    except ModuleNotFoundError as exc:
        # The drone's base install has no extras; a command that needs one says which.
        missing = DependencyError.from_missing(exc, f"uav-depth {args.command}")
        if missing is None:
            raise
        print(f"uav-depth {args.command}: error: {missing}", file=sys.stderr)
        return EXIT_ERROR
    except UavDepthError as exc:
        print(f"uav-depth {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR


def entry() -> None:  # console_scripts target
    if sys.argv[1:2] and sys.argv[1] in DAEMONS:
        SIGNALS.install(at_exec=True)   # before the subcommand table and any slow import (see cli.signals)
    sys.exit(main())


if __name__ == "__main__":
    entry()
