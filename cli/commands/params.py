"""uav-depth params default|check|table."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    sub.add_parser("default", help="print the built-in manual baseline as a parameter file")
    c = sub.add_parser("check", help="validate a parameter file with the daemon's rules; prints its hash "
                                     "(exit 78 when the daemon would refuse it)")
    c.add_argument("file")
    c.add_argument("--calibration", metavar="FILE",
                   help="also check it against this camera, as the daemon does at load: OpenCV's limits at the "
                        "image size, and a test render measured in the default ranging ROI")
    sub.add_parser("table", help="print the markdown table of keys, bounds and the paper's symbols")


def run(args: argparse.Namespace) -> int:
    import sys

    from uav_depth.cli.exit_codes import EXIT_CONFIG
    from uav_depth.core.errors import FileFormatError
    from uav_depth.core.params import DEFAULT_PARAMS, dump_params, load_params, params_table_markdown

    if args.action == "default":
        print(dump_params(DEFAULT_PARAMS), end="")
    elif args.action == "check":
        try:
            params = load_params(args.file)
        except FileFormatError as exc:   # unreadable, not UTF-8, not YAML: a params-file fault, like run's
            print(f"uav-depth params: error: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        extra = ""
        if args.calibration:
            extra = "; " + _check_against(params, args.file, args.calibration)
        print(f"{args.file}: valid, hash {params.hash()}{extra}")
    else:
        print(params_table_markdown())
    return 0


def _check_against(params, origin: str, calibration: str) -> str:
    """The daemon's load-time rules for ``params`` on this camera (raises ConfigError / CalibrationError)."""
    from uav_depth.core.calibration import load_calibration
    from uav_depth.core.rectify import Rectifier
    from uav_depth.daemon.ranging import RangingConfig, resolve_roi
    from uav_depth.daemon.stage import build_stage

    calib = Rectifier(load_calibration(calibration)).calibration
    roi = resolve_roi(None, calib.width, calib.height)
    build_stage(params, origin, RangingConfig(), calib, roi)
    return f"measures a test render at {calib.width}x{calib.height} in ROI {list(roi)}"
