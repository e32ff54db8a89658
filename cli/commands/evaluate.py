"""uav-depth evaluate LOGDIR [--params FILE] [--set KEY=VALUE ...] [--roi L,T,R,B] [--json]."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    p.add_argument("--params", help="parameter file (default: built-in manual baseline)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change one parameter of the file (or the baseline), e.g. --set sgbm.num_disparities=64 "
                        "(repeatable)")
    p.add_argument("--roi", metavar="L,T,R,B",
                   help="score inside this box, fractions of the image (as compute.roi), whatever the "
                        "parameters match: compares two files in the same box")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def parse_sets(items: list[str]) -> dict:
    """``--set KEY=VALUE`` items -> {dotted key: YAML value}; ConfigError naming --set when malformed."""
    import yaml

    from uav_depth.core.errors import ConfigError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key.count(".") != 1:
            raise ConfigError("--set", "must look like SECTION.KEY=VALUE (sgbm.num_disparities=64)", item)
        try:
            out[key] = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError:
            out[key] = value
    return out


def parse_roi(text: str | None):
    from uav_depth.core.errors import ConfigError

    if text is None:
        return None
    try:
        box = tuple(float(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4 or not (0 <= box[0] < box[2] <= 1 and 0 <= box[1] < box[3] <= 1):
        raise ConfigError("--roi", "must be four fractions L,T,R,B with 0 <= L < R <= 1 and 0 <= T < B <= 1", text)
    return box


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
    sets = parse_sets(args.overrides)
    if sets:
        params = params.replace(**sets)
    roi = parse_roi(args.roi)
    frames = list(iter_frames(args.logdir, require_reference=True))
    scores = evaluate_frames(params, frames, roi)
    if not scores:
        raise FileFormatError(f"{args.logdir}: no frame with a reference disparity (*_ref.npy/.pfm/.png)")
    mean = mean_scores(scores)
    references = summarize_references(frames)
    if roi is not None:
        region = f"--roi {list(roi)}"
    else:
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
    truth = any(s.truth_m is not None for s in scores)
    head = f"{'truth m':>9}{'branch m':>10}{'err%':>7}" if truth else ""
    print(f"{'frame':<28}{'mse':>9}{'psnr':>8}{'ssim':>7}{'bad1%':>8}{'bad2%':>8}{'valid':>7}{'ms':>7}{head}")
    for s in scores:
        tail = ""
        if truth:
            t = f"{s.truth_m:9.3f}" if s.truth_m is not None else f"{'-':>9}"
            b = f"{s.branch_m:10.3f}" if s.branch_m is not None else f"{'none':>10}"
            e = f"{s.branch_err_pct:7.2f}" if math.isfinite(s.branch_err_pct) else f"{'-':>7}"
            tail = t + b + e
        print(f"{s.id:<28}{s.mse:9.2f}{s.psnr:8.2f}{s.ssim:7.3f}{s.bad1:8.2f}{s.bad2:8.2f}{s.valid:7.3f}{s.ms:7.0f}"
              f"{tail}")
    m = mean
    tail = f"{'':>19}{m['branch_err_pct']:7.2f}" if truth else ""
    print(f"{'mean':<28}{m['mse']:9.2f}{m['psnr']:8.2f}{m['ssim']:7.3f}{m['bad1']:8.2f}{m['bad2']:8.2f}"
          f"{m['valid']:7.3f}{m['ms']:7.0f}{tail}")
    if truth:
        print(f"branch distance: median error {m['branch_err_median_pct']:.2f}%, mean {m['branch_err_pct']:.2f}% "
              "(a frame measured nothing counts 100%)")
    return 0
