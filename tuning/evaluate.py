"""Evaluate the disparity pipeline on logged frames with reference disparity."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import FileFormatError
from uav_depth.core.params import StereoParams
from uav_depth.core.session import FrameRecord

from uav_depth.tuning.metrics import METRIC_NAMES, in_box, score
from uav_depth.tuning.objective import scored_box


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

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("id", *METRIC_NAMES, "ms")}


def evaluate_frames(params: StereoParams, frames: Iterable[FrameRecord]) -> list[FrameScore]:
    """Run the pipeline on each frame that has a reference and score it (inside ``compute.roi``)."""
    pipeline = DisparityPipeline(params)
    out = []
    for frame in frames:
        ref = frame.load_reference()
        if ref is None:
            continue
        left, right = frame.load_pair()
        if ref.shape != left.shape[:2]:
            raise FileFormatError(f"{frame.ref_path}: reference is {ref.shape}, frame is {left.shape[:2]}")
        t0 = time.perf_counter()
        disp = pipeline.compute(left, right)
        ms = (time.perf_counter() - t0) * 1000.0
        s = score(*in_box(scored_box(params, ref.shape), ref, disp))
        out.append(FrameScore(frame.key, s.mse, s.psnr, s.ssim, s.bad1, s.bad2, s.valid, ms))
    return out


def mean_scores(scores: list[FrameScore]) -> dict[str, float]:
    keys = (*METRIC_NAMES, "ms")
    return {k: float(np.mean([getattr(s, k) for s in scores])) if scores else math.nan for k in keys}
