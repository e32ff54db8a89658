"""uav-depth demo: the main job on an embedded default, no hardware.

Synthesises a session (branch scenes at 0.5-2 m), runs the flown pipeline on it
and prints the scores and the branch distance it measures against the truth.
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
    from uav_depth.sim.scene import SceneConfig, write_session
    from uav_depth.core.session import iter_frames
    from uav_depth.core.params import DEFAULT_PARAMS

    try:
        from uav_depth.tuning.evaluate import evaluate_frames, mean_scores
    except ImportError:
        evaluate_frames = None
    from uav_depth.core.session import prepare_output

    prepare_output(args.out, args.overwrite)
    write_session(args.out, args.frames, args.seed, SceneConfig())
    print(f"synthetic session: {args.out} ({args.frames} frames, 1280x720)")
    if evaluate_frames is None:
        print("install uav-depth[tuning] to score it")
        return 0
    scores = evaluate_frames(DEFAULT_PARAMS, iter_frames(args.out, require_reference=True))
    print(f"{'frame':<28}{'mse':>9}{'psnr':>8}{'ssim':>7}{'bad2%':>8}{'valid':>7}{'ms':>7}")
    for s in scores:
        print(f"{s.id:<28}{s.mse:9.2f}{s.psnr:8.2f}{s.ssim:7.3f}{s.bad2:8.2f}{s.valid:7.3f}{s.ms:7.0f}")
    m = mean_scores(scores)
    print(f"{'mean':<28}{m['mse']:9.2f}{m['psnr']:8.2f}{m['ssim']:7.3f}{m['bad2']:8.2f}{m['valid']:7.3f}{m['ms']:7.0f}")
    return 0
