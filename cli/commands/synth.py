"""uav-depth synth OUTDIR: a synthetic session with exact reference disparity and truth."""

from __future__ import annotations

import argparse
import time


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("outdir", help="session directory to write (created)")
    p.add_argument("--frames", type=int, default=10, help="number of stereo pairs (default 10)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing session there (else: refused, exit 73)")
    p.add_argument("--seed", type=int, default=0, help="seed: the same seed gives the same pixels (default 0)")
    p.add_argument("--width", type=int, default=1280, help="image width, px (default 1280)")
    p.add_argument("--height", type=int, default=720, help="image height, px (default 720)")
    p.add_argument("--focal-px", type=float, default=700.0, help="focal length, px (default 700, ZED Mini-like)")
    p.add_argument("--baseline-m", type=float, default=0.063, help="stereo baseline, m (default 0.063)")
    p.add_argument("--distance-m", type=float, default=None,
                   help="fix the branch distance, m (default: varied 0.5-2 m per frame)")
    p.add_argument("--fixed-conditions", action="store_true",
                   help="keep imaging conditions fixed instead of varying them per frame")
    p.add_argument("--color", action="store_true", help="write BGR colour frames instead of grey")


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.progress import Progress
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.session import prepare_output
    from uav_depth.sim.scene import SceneConfig, write_session

    if args.frames < 1:
        raise ConfigError("--frames", "must be at least 1", args.frames)
    kw = dict(width=args.width, height=args.height, focal_px=args.focal_px, baseline_m=args.baseline_m,
              color=args.color)
    if args.distance_m is not None:
        kw["branch_distance_m"] = args.distance_m
    base = SceneConfig(**kw)
    prepare_output(args.outdir, args.overwrite)
    progress = Progress()
    progress.phase(f"rendering {args.frames} synthetic pairs {args.width}x{args.height} into {args.outdir}")
    t0 = time.perf_counter()
    write_session(args.outdir, args.frames, args.seed, base, vary_scenes=not args.fixed_conditions,
                  fixed_distance=args.distance_m, progress=progress.counter("rendered"))
    dt = time.perf_counter() - t0
    print(f"wrote {args.frames} frames to {args.outdir} ({dt / args.frames * 1000:.0f} ms per pair incl. PNG)")
    return 0
