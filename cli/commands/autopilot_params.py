"""uav-depth autopilot-params --config FILE: the autopilot settings the daemon's readings need.

Loads the run config as ``run --check`` does (the parameter file with its test render
gives the range DISTANCE_SENSOR states) and prints, for ArduPilot (MAVProxy ``param
set`` lines) or PX4, the value of each parameter the readings depend on, with the rule
it follows (:mod:`uav_depth.daemon.link.settings`: the same rules the running daemon
checks the autopilot against). Exit codes as ``run --check``.
"""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="run config (YAML); default $UAV_DEPTH_CONFIG")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="set a config key, as for run (repeatable)")
    p.add_argument("--params-file", metavar="FILE", help="same as --set params_file=FILE")
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="the flight stack to print settings for (default ardupilot)")
    p.set_defaults(mavlink_url=None, log_dir=None)


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.commands.run import error_line, exit_code, overrides_from_args
    from uav_depth.cli.sources import SOURCES
    from uav_depth.core.errors import UavDepthError
    from uav_depth.daemon.config import load_run_config
    from uav_depth.daemon.link.contract import stated_range_cm
    from uav_depth.daemon.link.settings import RULES, STACKS, WireRange
    from uav_depth.daemon.link.vocabulary import orientation_code
    from uav_depth.daemon.preflight import preflight
    from uav_depth.daemon.sources import create_source

    err = error_line("autopilot-params")
    try:
        config = load_run_config(args.config, overrides_from_args(args), sources=SOURCES)
        report = preflight(config, create_source(config.source))
    except UavDepthError as exc:
        err(exc)
        return exit_code(exc)
    if report.limits is None:
        err("the range comes from the camera's calibration, read at start-up: give the config a calibration")
        return 1
    rng = WireRange(*stated_range_cm(report.limits), orientation_code(config.mavlink.orientation))
    print("\n".join(settings_lines(args.autopilot, rng, RULES[STACKS[args.autopilot]])))
    return 0


def settings_lines(stack: str, rng, rules) -> list[str]:
    """The printed lines: a header, then ``param set NAME VALUE  # why`` (ArduPilot) or ``NAME VALUE  # why``."""
    from uav_depth.daemon.link.settings import recommended

    lines = [f"# {'ArduPilot' if stack == 'ardupilot' else 'PX4'} settings for what uav-depth sends: "
             f"min_distance {rng.min_cm} cm, max_distance {rng.max_cm} cm, orientation {rng.orientation}"]
    rows = recommended(rules, rng)
    for group, title in ((False, None), (True, "# after RNGFND1_TYPE 10 and a reboot ('param fetch' first):")):
        chosen = [(rule, value, why) for rule, value, why in rows if rule.after_reboot is group]
        if chosen and title:
            lines.append(title)
        for rule, value, why in chosen:
            cmd = f"param set {rule.param} {value:g}" if stack == "ardupilot" else f"{rule.param} {value:g}"
            lines.append(f"{cmd:<28}# {why}")
    return lines
