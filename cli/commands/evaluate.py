"""uav-depth evaluate LOGDIR [--params FILE] [--convention bench|paper] [--json]."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    p.add_argument("--params", help="parameter file (default: built-in manual baseline)")
    p.add_argument("--convention", choices=("bench", "paper"), default="bench",
                   help="bench (default): the map the daemon ranges on (confident measured pixels), error over "
                        "ground-truth pixels with holes filled as the KITTI devkit does, density beside it, the "
                        "unmatchable left strip left out, PSNR against a fixed peak; paper: the WLS map, invalid "
                        "= 0, PSNR peak per frame (Lin et al. 2025)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    import json
    import math

    from uav_depth.core.errors import FileFormatError, UavDepthError
    from uav_depth.core.params import DEFAULT_PARAMS, load_params
    from uav_depth.core.session import iter_frames

    from uav_depth.tuning.frames import FrameSet, load_frame
    from uav_depth.tuning.metrics import METRIC_NAMES
    from uav_depth.tuning.objective import FITNESS, evaluate
    from uav_depth.tuning.reference.provenance import summarize_references
    from uav_depth.tuning.report import sources_text

    params = load_params(args.params) if args.params else DEFAULT_PARAMS
    records = list(iter_frames(args.logdir, require_reference=True))
    if not records:
        raise FileFormatError(f"{args.logdir}: no frame with a reference disparity (*_ref.npy/.pfm/.png)")
    frames = FrameSet("evaluate", tuple(load_frame(r) for r in records))
    ev = evaluate(params, frames, FITNESS["flown" if args.convention == "bench" else "mse"], full=True,
                  convention=args.convention)
    if not ev.ok:
        raise UavDepthError(f"{args.logdir}: these parameters cannot be scored: {ev.reason}")
    names = [n for n in (*METRIC_NAMES[args.convention], "branch") if n in ev.metrics]
    region = "whole frame" if params.compute.whole_frame else f"compute.roi {list(params.compute.roi)}"
    references = summarize_references(records)
    if args.json:
        clean = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # noqa: E731
        doc = {"params_hash": params.hash(), "scored": region, "convention": args.convention,
               "references": references, "frames": [{k: clean(v) for k, v in f.items()} for f in ev.frame_metrics],
               "mean": {k: clean(v) for k, v in {**ev.metrics, "ms": ev.ms}.items()}}
        print(json.dumps(doc, default=str))
        return 0
    against = sources_text({src["description"]: src["frames"] for src in references["sources"]})
    print(f"scored: {region}, {args.convention} convention; measured against: {against}")
    print(f"{'frame':<28}" + "".join(f"{n:>9}" for n in (*names, "ms")))
    for f in ev.frame_metrics:
        print(f"{f['id']:<28}" + "".join(f"{f.get(n, math.nan):9.3f}" for n in names) + f"{f['ms']:9.0f}")
    print(f"{'mean':<28}" + "".join(f"{ev.metrics[n]:9.3f}" for n in names) + f"{ev.ms:9.0f}")
    return 0
