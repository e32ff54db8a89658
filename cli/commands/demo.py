"""uav-depth demo: the main job on an embedded default, no hardware.

Synthesises a session (branch scenes at 0.5-2 m), runs what flies on it (the
flight parameters for its camera and resolution, and the daemon's ranging) and
prints the branch distance it measures against the truth, frame by frame.
"""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="uav-depth-demo", help="where to write the session (default ./uav-depth-demo)")
    p.add_argument("--frames", type=int, default=3, help="number of synthetic pairs (default 3)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing session there (else: refused, exit 73)")
    p.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from uav_depth.core.params.flight import flight_params
    from uav_depth.cli.progress import progress_line
    from uav_depth.core.session import iter_frames, prepare_output
    from uav_depth.sim.scene import SceneConfig, write_session

    scene = SceneConfig()
    # What flies: the flight settings for this camera and resolution (deploy/params-flight.yaml at 1280x720)
    params = flight_params(scene.focal_px, scene.baseline_m)
    prepare_output(args.out, args.overwrite)
    print(f"rendering {args.frames} synthetic pairs {scene.width}x{scene.height} into {args.out} ...", flush=True)
    write_session(args.out, args.frames, args.seed, scene, progress=progress_line("rendered"))
    try:    # after the first line: the tuner's imports take seconds on a small machine
        from uav_depth.tuning.frames import FrameSet, load_frame
        from uav_depth.tuning.objective import FITNESS, evaluate
    except ImportError:
        evaluate = None
    if evaluate is None:
        print("install uav-depth[tuning] to score it")
        return 0
    print(f"flying the flight parameters for f {scene.focal_px:g} px (hash {params.hash()}; "
          "uav-depth bench prints how they were chosen)")
    import math

    import numpy as np

    frames = FrameSet("demo", tuple(load_frame(r) for r in iter_frames(args.out, require_reference=True)))
    ev = evaluate(params, frames, FITNESS["flown"], full=True)
    print(f"{'frame':<24}{'truth m':>9}{'measured m':>12}{'error %':>9}{'bad2%':>8}{'density':>8}{'ms':>7}")
    for f in ev.frame_metrics:
        meas = f"{f['branch_m']:12.3f}" if math.isfinite(f.get("branch_m", math.nan)) else f"{'none':>12}"
        truth = f"{f['truth_m']:9.3f}" if "truth_m" in f else f"{'-':>9}"
        print(f"{f['id']:<24}{truth}{meas}{f.get('branch', math.nan):9.2f}{f['bad2']:8.2f}{f['density']:8.3f}"
              f"{f['ms']:7.0f}")
    # Why a frame went out with no distance (what the daemon would log): its reading, run again.
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.tuning.objective import branch_reading

    pipeline = None
    for frame, f in zip(frames.frames, ev.frame_metrics):
        if "branch_m" in f and not math.isfinite(f["branch_m"]):
            pipeline = pipeline or flight_pipeline(params)
            m = branch_reading(frame, pipeline.run(frame.left, frame.right), params)
            print(f"  {f['id']}: {'too close' if m.too_close else 'no measurement'}: {m.reason}")
    errs = [f["branch"] for f in ev.frame_metrics if "branch" in f]
    print(f"branch distance: median error {float(np.median(errs)) if errs else math.nan:.2f}% over "
          f"{len(ev.frame_metrics)} frames (a frame measured nothing counts 100%); {ev.ms:.0f} ms per frame; "
          "map metrics in the benchmark convention (uav-depth evaluate --help)")
    return 0
