"""uav-depth run --config FILE: the on-board daemon (stereo -> branch distance -> MAVLink DISTANCE_SENSOR).

Exit codes: 0 after a clean stop (SIGTERM, SIGINT, a replay that ended); 78
(EX_CONFIG) when the config, calibration, parameter file, signing key or log
directory is unusable, so systemd does not restart-loop on a typo; 69
(EX_UNAVAILABLE) when the camera (or the replay's files) is missing at start-up,
so systemd may retry until it appears; 1 for other errors. ``--check`` exits with
the code ``run`` would.
"""

from __future__ import annotations

import argparse

from uav_depth.cli.overrides import CONFIG_EXAMPLE, add_set_option, parse_sets


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="run config (YAML); default $UAV_DEPTH_CONFIG")
    add_set_option(p, "the run config", CONFIG_EXAMPLE, "; wins over UAV_DEPTH_* environment variables and the file")
    p.add_argument("--params-file", metavar="FILE", help="same as --set params_file=FILE")
    p.add_argument("--mavlink-url", metavar="URL", help="same as --set mavlink.url=URL")
    p.add_argument("--log-dir", metavar="DIR", help="same as --set logging.dir=DIR")
    p.add_argument("--check", action="store_true",
                   help="load everything run would (config, signing key, log directory, calibration, parameter "
                        "file with every rule, replay files; camera presence as a warning), print what was "
                        "checked and exit with run's exit code")
    p.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))


def overrides_from_args(args: argparse.Namespace) -> dict:
    """The run config's command-line keys: the ``--set`` items, then the options that name one key."""
    out = parse_sets(args.overrides)
    for key, value in (("params_file", args.params_file), ("mavlink.url", args.mavlink_url),
                       ("logging.dir", args.log_dir)):
        if value is not None:
            out[key] = value
    return out


def setup_logging(level: str) -> None:
    """Plain lines for journald (it adds time and unit); no colours, no timestamps."""
    import logging
    import sys

    logging.basicConfig(level=getattr(logging, level.upper()), stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")


def exit_code(exc) -> int:
    """The exit code (module docstring) for a failure of ``run``, ``run --check`` or ``sitl``: the one mapping."""
    from uav_depth.cli.exit_codes import EXIT_CONFIG, EXIT_ERROR, EXIT_UNAVAILABLE
    from uav_depth.core.errors import (CalibrationError, ConfigError, DependencyError, FileFormatError, LinkError,
                                       SourceError)

    if isinstance(exc, (ConfigError, CalibrationError, FileFormatError, DependencyError)):
        return EXIT_CONFIG
    if isinstance(exc, (SourceError, LinkError)):
        return EXIT_UNAVAILABLE
    return EXIT_ERROR


def error_line(command: str):
    """The one line a start-up or run failure prints: ``uav-depth run: error: ...``."""
    import sys

    return lambda exc: print(f"uav-depth {command}: error: {exc}", file=sys.stderr, flush=True)


def serve(service, signals, command: str, cleanup=None) -> int:
    """Run ``service`` until ``signals.stop`` is set (SIGTERM, SIGINT); SIGUSR1 logs a frame, SIGHUP reloads.

    ``signals``: the process's :class:`~uav_depth.cli.signals.Signals`, installed at
    exec. Maps what stops it to the exit codes above; ``cleanup`` runs whatever
    happens. The handlers only set events; the service's threads and main loop do the work.
    """
    import logging
    import os
    import sys

    from uav_depth.core.errors import UavDepthError

    err = error_line(command)
    stop = signals.stop
    if signals.reload.is_set():
        logging.getLogger("uav_depth.service").info("SIGHUP before start-up: nothing to reload yet (the parameter "
                                                     "file is read now)")
    signals.attach(service.request_reload, service.request_log_frame)
    if stop.is_set():
        return stopped_before_start(signals, command, cleanup)
    log_signals_installed(signals)
    try:
        report = service.run(stop)
    except UavDepthError as exc:
        err(exc)
        return exit_code(exc)
    finally:
        if cleanup is not None:
            cleanup()
    if service.ended:
        logging.getLogger("uav_depth.service").info("source ended: %s", service.ended)
    if report.abandoned:
        # A thread left inside OpenCV would be unwound by the interpreter's exit (pthread_exit
        # through OpenCV's catch-all handlers), which aborts the process ("FATAL: exception not
        # rethrown", SIGABRT). Shutdown already said what it abandoned: leave without finalising.
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


def stopped_before_start(signals, command: str, cleanup=None) -> int:
    """A SIGTERM/SIGINT arrived during start-up: nothing ran yet, exit 0 with one line."""
    import logging

    if cleanup is not None:
        cleanup()
    log_signals_installed(signals)
    logging.getLogger("uav_depth.service").info("%s: stopped before start-up finished (%s)", command,
                                                 ", ".join(signals.received) or "stop requested")
    return 0


def log_signals_installed(signals) -> None:
    import logging

    ms, held = signals.installed_after_ms, signals.held
    logging.getLogger("uav_depth.service").info(
        "signal handlers installed %s after exec%s", f"{ms:.0f} ms" if ms is not None else "(time unknown)",
        f" ({', '.join(held)} sent before then: held blocked, handled now)" if held else "")


def check(config) -> int:
    """``run --check``: everything run would load (see uav_depth.daemon.preflight); run's exit codes."""
    from uav_depth.core.errors import UavDepthError
    from uav_depth.daemon.preflight import preflight
    from uav_depth.daemon.sources import create_source

    try:
        report = preflight(config, create_source(config.source))
    except UavDepthError as exc:
        error_line("run --check")(exc)
        return exit_code(exc)
    for line in report.checked:
        print(f"checked: {line}")
    for line in report.warnings:
        print(f"warning: {line}")
    print(f"config valid: {config.summary()}")
    return 0


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.signals import install_once

    signals = install_once()

    from uav_depth.cli.sources import SOURCES
    from uav_depth.daemon.config import load_run_config
    from uav_depth.core.errors import UavDepthError

    setup_logging(args.log_level)
    err = error_line("run --check" if args.check else "run")
    try:
        config = load_run_config(args.config, overrides_from_args(args), sources=SOURCES)
    except UavDepthError as exc:
        err(exc)
        return exit_code(exc)
    if args.check:
        return check(config)

    if signals.stop.is_set():
        return stopped_before_start(signals, "run")

    from uav_depth.daemon.service import Service

    try:
        service = Service(config)
    except UavDepthError as exc:
        err(exc)
        return exit_code(exc)
    return serve(service, signals, "run")
