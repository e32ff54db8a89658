"""uav-depth evaluate LOGDIR [--params FILE] [--set KEY=VALUE ...] [--roi L,T,R,B] [--convention bench|paper] [--json]."""

from __future__ import annotations

import argparse

from uav_depth.cli.overrides import add_set_option, apply_sets


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    p.add_argument("--params", help="parameter file (default: built-in manual baseline)")
    add_set_option(p, "the file (or the baseline)")
    p.add_argument("--roi", metavar="L,T,R,B",
                   help="score inside this box, fractions of the image (as compute.roi), whatever the "
                        "parameters match: compares two files in the same box")
    p.add_argument("--convention", choices=("bench", "paper"), default="bench",
                   help="bench (default): the map the daemon ranges on (confident measured pixels), error over "
                        "ground-truth pixels with holes filled as the KITTI devkit does, density beside it, the "
                        "unmatchable left strip left out, PSNR against a fixed peak; paper: the WLS map, invalid "
                        "= 0, PSNR peak per frame (Lin et al. 2025)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


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

    from uav_depth.cli.progress import Progress
    from uav_depth.core.errors import FileFormatError
    from uav_depth.core.params import DEFAULT_PARAMS, load_params
    from uav_depth.core.session import iter_frames

    params = load_params(args.params) if args.params else DEFAULT_PARAMS
    params = apply_sets(params, args.overrides)
    roi = parse_roi(args.roi)
    records = list(iter_frames(args.logdir, require_reference=True))
    if not records:
        raise FileFormatError(f"{args.logdir}: no frame with a reference disparity (*_ref.npy/.pfm/.png)")
    progress = Progress()
    progress.phase(f"loading {len(records)} frame(s) from {args.logdir}")
    from uav_depth.tuning.metrics import METRIC_NAMES              # after the first line: seconds of imports
    from uav_depth.tuning.reference.provenance import summarize_references

    frame_metrics = score(params, records, args.convention, roi, args.logdir, progress)
    names = list(METRIC_NAMES[args.convention])
    if roi is not None:
        region = f"--roi {list(roi)}"
    else:
        region = "whole frame" if params.compute.whole_frame else f"compute.roi {list(params.compute.roi)}"
    references = summarize_references(records)
    per, mean = tabulate(frame_metrics, names)
    if args.json:
        doc = {"params_hash": params.hash(), "scored": region, "convention": args.convention,
               "references": references, "frames": [{k: _finite(v) for k, v in r.items()} for r in per],
               "mean": {k: _finite(v) for k, v in mean.items()}}
        print(json.dumps(doc, default=str))
        return 0
    print_table(per, mean, names, region, args.convention, references)
    return 0


def score(params, records, convention: str, roi, logdir: str, progress) -> list[dict]:
    """The metrics of every frame of ``records`` under ``params``, loaded and scored one frame at a time
    (the pipeline keeps nothing between frames), so that a terminal sees each scored."""
    from uav_depth.core.errors import UavDepthError
    from uav_depth.tuning.frames import FrameSet, load_frame
    from uav_depth.tuning.objective import FITNESS, evaluate

    frames = []
    for r in records:
        frames.append(load_frame(r))
        progress.step("frames loaded", len(frames), len(records))
    progress.phase(f"scoring parameters {params.hash()} on {len(frames)} frame(s)")
    fitness = FITNESS["flown" if convention == "bench" else "mse"]
    frame_metrics = []
    for frame in frames:
        ev = evaluate(params, FrameSet("evaluate", (frame,)), fitness, full=True, convention=convention,
                      score_roi=roi)
        if not ev.ok:
            raise UavDepthError(f"{logdir}: these parameters cannot be scored: {ev.reason}")
        frame_metrics.extend(ev.frame_metrics)
        progress.step("frames scored", len(frame_metrics), len(frames))
    return frame_metrics


def _finite(v):
    """A non-finite float as None (JSON has no NaN); anything else as it is."""
    import math

    return None if isinstance(v, float) and not math.isfinite(v) else v


def tabulate(frame_metrics: list[dict], names: list[str]) -> tuple[list[dict], dict]:
    """One row per frame (the metrics, ms, the branch's truth, reading and error in %) and their means;
    the branch error's mean and median over the frames that have one."""
    import math

    import numpy as np

    per = []
    for f in frame_metrics:
        row = {k: f[k] for k in ("id", *names, "ms")}
        row.update(truth_m=f.get("truth_m"), branch_m=_finite(f.get("branch_m")),
                   branch_err_pct=f.get("branch", math.nan))
        per.append(row)
    errs = [r["branch_err_pct"] for r in per if math.isfinite(r["branch_err_pct"])]
    mean = {k: float(np.mean([r[k] for r in per])) for k in (*names, "ms")} | {
            "branch_err_pct": float(np.mean(errs)) if errs else math.nan,
            "branch_err_median_pct": float(np.median(errs)) if errs else math.nan}
    return per, mean


def print_table(per: list[dict], mean: dict, names: list[str], region: str, convention: str, references) -> None:
    """The text report: what was scored against what, a row per frame, the means, the branch error."""
    import math

    from uav_depth.tuning.report import sources_text

    against = sources_text({src["description"]: src["frames"] for src in references["sources"]})
    print(f"scored: {region}, {convention} convention; measured against: {against}")
    truth = math.isfinite(mean["branch_err_pct"]) or any(r["truth_m"] is not None for r in per)
    head = f"{'truth m':>9}{'branch m':>10}{'err%':>7}" if truth else ""
    print(f"{'frame':<28}" + "".join(f"{n:>9}" for n in (*names, "ms")) + head)
    for r in per:
        tail = ""
        if truth:
            t = f"{r['truth_m']:9.3f}" if r["truth_m"] is not None else f"{'-':>9}"
            b = f"{r['branch_m']:10.3f}" if r["branch_m"] is not None else f"{'none':>10}"
            e = f"{r['branch_err_pct']:7.2f}" if math.isfinite(r["branch_err_pct"]) else f"{'-':>7}"
            tail = t + b + e
        print(f"{r['id']:<28}" + "".join(f"{r[n]:9.3f}" for n in names) + f"{r['ms']:9.0f}" + tail)
    print(f"{'mean':<28}" + "".join(f"{mean[n]:9.3f}" for n in names) + f"{mean['ms']:9.0f}"
          + (f"{'':>19}{mean['branch_err_pct']:7.2f}" if truth else ""))
    if truth:
        print(f"branch distance: median error {mean['branch_err_median_pct']:.2f}%, mean {mean['branch_err_pct']:.2f}% "
              "(a frame measured nothing counts 100%)")
