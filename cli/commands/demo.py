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
        from uav_depth.tuning.frames import FrameSet, load_frame
        from uav_depth.tuning.objective import FITNESS, evaluate
    except ImportError:
        evaluate = None
    from uav_depth.core.session import prepare_output

    prepare_output(args.out, args.overwrite)
    write_session(args.out, args.frames, args.seed, SceneConfig())
    print(f"synthetic session: {args.out} ({args.frames} frames, 1280x720)")
    if evaluate is None:
        print("install uav-depth[tuning] to score it")
        return 0
    frames = FrameSet("demo", tuple(load_frame(r) for r in iter_frames(args.out, require_reference=True)))
    ev = evaluate(DEFAULT_PARAMS, frames, FITNESS["flown"], full=True)
    names = ("mae", "bad2", "density", "branch")
    print("benchmark convention on the map the daemon ranges on (uav-depth evaluate --help)")
    print(f"{'frame':<28}" + "".join(f"{n:>9}" for n in (*names, "ms")))
    for f in ev.frame_metrics:
        print(f"{f['id']:<28}" + "".join(f"{f[n]:9.3f}" for n in names) + f"{f['ms']:9.0f}")
    print(f"{'mean':<28}" + "".join(f"{ev.metrics[n]:9.3f}" for n in names) + f"{ev.ms:9.0f}")
    return 0
