"""uav-depth evaluate LOGDIR [--params FILE] [--json]."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    p.add_argument("--params", help="parameter file (default: built-in manual baseline)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    import json
    import math

    from uav_depth.core.errors import FileFormatError
    from uav_depth.core.params import DEFAULT_PARAMS, load_params
    from uav_depth.core.session import iter_frames

    from uav_depth.tuning.evaluate import evaluate_frames, mean_scores
    from uav_depth.tuning.reference.provenance import summarize_references
    from uav_depth.tuning.report import sources_text

    params = load_params(args.params) if args.params else DEFAULT_PARAMS
    frames = list(iter_frames(args.logdir, require_reference=True))
    scores = evaluate_frames(params, frames)
    if not scores:
        raise FileFormatError(f"{args.logdir}: no frame with a reference disparity (*_ref.npy/.pfm/.png)")
    mean = mean_scores(scores)
    references = summarize_references(frames)
    region = "whole frame" if params.compute.whole_frame else f"compute.roi {list(params.compute.roi)}"
    if args.json:
        clean = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # noqa: E731
        doc = {"params_hash": params.hash(), "scored": region, "references": references,
               "frames": [{k: clean(v) for k, v in s.as_dict().items()} for s in scores],
               "mean": {k: clean(v) for k, v in mean.items()}}
        print(json.dumps(doc, default=str))
        return 0
    print(f"scored: {region}; measured against: "
          + sources_text({src["description"]: src["frames"] for src in references["sources"]}))
    print(f"{'frame':<28}{'mse':>9}{'psnr':>8}{'ssim':>7}{'bad1%':>8}{'bad2%':>8}{'valid':>7}{'ms':>7}")
    for s in scores:
        print(f"{s.id:<28}{s.mse:9.2f}{s.psnr:8.2f}{s.ssim:7.3f}{s.bad1:8.2f}{s.bad2:8.2f}{s.valid:7.3f}{s.ms:7.0f}")
    m = mean
    print(f"{'mean':<28}{m['mse']:9.2f}{m['psnr']:8.2f}{m['ssim']:7.3f}{m['bad1']:8.2f}{m['bad2']:8.2f}"
          f"{m['valid']:7.3f}{m['ms']:7.0f}")
    return 0
