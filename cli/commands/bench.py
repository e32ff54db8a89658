"""uav-depth bench [--params FILE] [--levers] [--json]: the daemon pipeline against OpenCV's sample pipeline."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", help="parameter file to time as 'flight' (default: the shipped flight settings, "
                                    "as deploy/params-flight.yaml)")
    p.add_argument("--frames", type=int, default=12, help="synthetic pairs, branch 0.5..2 m (default 12)")
    p.add_argument("--rounds", type=int, default=20, help="passes over the frames for the fast pipelines (default 20)")
    p.add_argument("--naive-rounds", type=int, default=2,
                   help="passes for the naive full-frame pipeline, interleaved with the others (default 2)")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    p.add_argument("--levers", action="store_true",
                   help="time one lever at a time from the naive pipeline to the flight settings")
    p.add_argument("--threads", type=int, help="cv2.setNumThreads before timing (default: OpenCV's choice)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    import json

    from uav_depth.cli.benchmark import bench, format_report
    from uav_depth.cli.progress import QUIET, Progress
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.params import load_params
    from uav_depth.core.params.flight import flight_params

    for name in ("frames", "rounds", "naive_rounds"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')}", "must be at least 1", getattr(args, name))
    if args.width < 64 or args.height < 64:
        raise ConfigError("--width/--height", "must be at least 64", f"{args.width}x{args.height}")
    if args.threads is not None and args.threads < 0:
        raise ConfigError("--threads", "must be 0 (no threading) or more", args.threads)
    # The built-in flight settings are for the ZED Mini-like camera the scenes model (700 px at 1280 wide).
    flight = load_params(args.params) if args.params else flight_params(focal_px=700.0 * args.width / 1280.0)
    progress = QUIET if args.json else Progress()
    out = bench(flight, frames=args.frames, rounds=args.rounds, naive_rounds=args.naive_rounds, width=args.width,
                height=args.height, seed=args.seed, levers=args.levers, threads=args.threads, progress=progress)
    out["flight_params_source"] = args.params or "built-in flight_params()"
    if args.json:
        print(json.dumps(out))
    else:
        print(format_report(out))
    return 0
