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
    from uav_depth.cli.benchmark import flight_params
    from uav_depth.cli.commands.synth import progress_line
    from uav_depth.core.session import iter_frames, prepare_output
    from uav_depth.sim.scene import SceneConfig, write_session

    try:
        from uav_depth.tuning.evaluate import evaluate_frames, mean_scores
    except ImportError:
        evaluate_frames = None
    scene = SceneConfig()
    # What flies: the flight settings for this camera and resolution (deploy/params-flight.yaml at 1280x720)
    params = flight_params(scene.focal_px, scene.baseline_m)
    prepare_output(args.out, args.overwrite)
    print(f"rendering {args.frames} synthetic pairs {scene.width}x{scene.height} into {args.out} ...", flush=True)
    write_session(args.out, args.frames, args.seed, scene, progress=progress_line("rendered"))
    if evaluate_frames is None:
        print("install uav-depth[tuning] to score it")
        return 0
    print(f"flying the flight parameters for f {scene.focal_px:g} px (hash {params.hash()}; "
          "uav-depth bench prints how they were chosen)")
    scores = evaluate_frames(params, iter_frames(args.out, require_reference=True))
    print(f"{'frame':<24}{'truth m':>9}{'measured m':>12}{'error %':>9}{'bad2%':>8}{'valid':>7}{'ms':>7}")
    for s in scores:
        meas = f"{s.branch_m:12.3f}" if s.branch_m is not None else f"{'none':>12}"
        truth = f"{s.truth_m:9.3f}" if s.truth_m is not None else f"{'-':>9}"
        print(f"{s.id:<24}{truth}{meas}{s.branch_err_pct:9.2f}{s.bad2:8.2f}{s.valid:7.3f}{s.ms:7.0f}")
    m = mean_scores(scores)
    print(f"branch distance: median error {m['branch_err_median_pct']:.2f}% over {len(scores)} frames "
          f"(a frame measured nothing counts 100%); {m['ms']:.0f} ms per frame")
    return 0
