"""uav-depth params default|check|table."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    sub.add_parser("default", help="print the built-in manual baseline as a parameter file")
    c = sub.add_parser("check", help="validate parameter files with the daemon's rules and run each on a test "
                                     "render in a child process (OpenCV's crashes are native); prints each one's "
                                     "hash (exit 78 when the daemon would refuse any)")
    c.add_argument("file", nargs="+")
    c.add_argument("--calibration", metavar="FILE",
                   help="check them against this camera, as the daemon does at load: OpenCV's limits at the image "
                        "size, and a test render measured in the default ranging ROI; without it the test render "
                        "runs at a 1280x720 reference camera (widened to the search range) and only a crash or a "
                        "hang refuses")
    sub.add_parser("table", help="print the markdown table of keys, bounds and the paper's symbols")


def run(args: argparse.Namespace) -> int:
    from uav_depth.core.params import DEFAULT_PARAMS, dump_params, params_table_markdown

    if args.action == "default":
        print(dump_params(DEFAULT_PARAMS), end="")
    elif args.action == "check":
        return _check_files(args.file, args.calibration)
    else:
        print(params_table_markdown())
    return 0


def _check_files(files: list[str], calibration: str | None) -> int:
    """One line per file (stdout when valid, stderr when not); 78 when any is refused."""
    import sys

    from uav_depth.cli.exit_codes import EXIT_CONFIG
    from uav_depth.core.calibration import load_calibration
    from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
    from uav_depth.core.params import load_params
    from uav_depth.core.rectify import Rectifier
    from uav_depth.daemon.trial import Trials

    calib = Rectifier(load_calibration(calibration)).calibration if calibration else None
    trials = Trials()
    code = 0
    try:
        for path in files:
            try:
                params = load_params(path)
                note = _trial(params, path, calib, trials)
            except (ConfigError, FileFormatError, CalibrationError) as exc:   # one line, as run's, naming the file
                text = str(exc) if str(exc).startswith(path) else f"{path}: {exc}"
                print(f"uav-depth params: error: {text}", file=sys.stderr, flush=True)
                code = EXIT_CONFIG
                continue
            print(f"{path}: valid, hash {params.hash()}; {note}", flush=True)
    finally:
        trials.close()
    return code


def _trial(params, origin: str, calib, trials) -> str:
    """The daemon's load-time rules for ``params`` on ``calib`` (None: the reference camera, crashes only)."""
    import math

    from uav_depth.core.calibration import Calibration
    from uav_depth.core.ranging import RangingConfig, resolve_roi
    from uav_depth.daemon.stage import build_stage
    from uav_depth.daemon.trial import Job

    if calib is not None:
        roi = resolve_roi(None, calib.width, calib.height)
        build_stage(params, origin, RangingConfig(), calib, roi, trials)
        return f"measures a test render at {calib.width}x{calib.height} in ROI {list(roi)} (in a child process)"
    sg, scale = params.sgbm, params.compute.scale
    width = max(1280, math.ceil((sg.min_disparity + sg.num_disparities + sg.block_size // 2 + 2) / scale) + 1)
    ref = Calibration(focal_px=700.0, baseline_m=0.063, width=width, height=720)
    trials.run(Job(params, origin, RangingConfig(), ref, resolve_roi(None, ref.width, ref.height)))
    return (f"ran a test render at a {width}x720 reference camera in a child process (--calibration checks it "
            "against yours)")
