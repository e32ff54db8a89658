"""Evaluate the disparity pipeline on logged frames with reference disparity."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.params import StereoParams
from uav_depth.core.session import FrameRecord

from uav_depth.tuning.frames import load_frame
from uav_depth.tuning.metrics import METRIC_NAMES, in_box, score
from uav_depth.tuning.objective import branch_measurement, scored_box


@dataclass(frozen=True)
class FrameScore:
    id: str
    mse: float
    psnr: float
    ssim: float
    bad1: float
    bad2: float
    valid: float
    ms: float
    #: the daemon's ranging on this frame and its truth (synthetic sessions, imported truth), when known
    truth_m: float | None = None
    branch_m: float | None = None
    branch_err_pct: float = math.nan

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("id", *METRIC_NAMES, "ms", "truth_m", "branch_m", "branch_err_pct")}


def evaluate_frames(params: StereoParams, frames: Iterable[FrameRecord],
                    roi: tuple[float, float, float, float] | None = None) -> list[FrameScore]:
    """Run the pipeline on each frame that has a reference and score it.

    Scored inside ``roi`` ([left, top, right, bottom] fractions of the image) when given, so that
    two parameter files are compared in the same box; else inside the parameters' ``compute.roi``.
    Where the frame's truth is known, the daemon's ranging stage reads the branch distance too.
    """
    pipeline = DisparityPipeline(params)
    box_params = params if roi is None else params.replace(**{"compute.roi": tuple(roi)})
    out = []
    for record in frames:
        frame = load_frame(record)
        ref = frame.reference
        if ref is None:
            continue
        t0 = time.perf_counter()
        result = pipeline.run(frame.left, frame.right)
        ms = (time.perf_counter() - t0) * 1000.0
        s = score(*in_box(scored_box(box_params, ref.shape), ref, result.disparity))
        truth = branch = None
        err = math.nan
        if frame.has_branch:
            truth, branch, err = frame.branch_distance_m, *branch_measurement(frame, result, params)
        out.append(FrameScore(record.key, s.mse, s.psnr, s.ssim, s.bad1, s.bad2, s.valid, ms, truth, branch, err))
    return out


def mean_scores(scores: list[FrameScore]) -> dict[str, float]:
    keys = (*METRIC_NAMES, "ms")
    out = {k: float(np.mean([getattr(s, k) for s in scores])) if scores else math.nan for k in keys}
    errs = [s.branch_err_pct for s in scores if math.isfinite(s.branch_err_pct)]
    out["branch_err_pct"] = float(np.mean(errs)) if errs else math.nan
    out["branch_err_median_pct"] = float(np.median(errs)) if errs else math.nan
    return out
