"""The scale sanity check: a sample SGBM run against a reference, before it poisons a tuning run.

A reference in the wrong unit is the commonest import mistake: Middlebury's 8-bit
PNGs store disparity x4 or x8, KITTI's 16-bit PNGs x256, a map computed at half
resolution is x0.5. SGBM with generous settings is right on most textured pixels,
so the median of reference / SGBM over pixels both answer is the factor by which
the reference is off (1 when it is right). A flagged ratio comes with the scale
that would fix it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS, SPEC_BY_KEY

#: A reference off by this factor or more (either way) is flagged. Real scale
#: mistakes are x2 or more (half-size maps, Middlebury's x4/x8, KITTI's x256);
#: SGBM's own bias on a right reference stays within a few %.
RATIO_TOLERANCE = 1.5
#: Fewer pixels than this where both answer (and SGBM is at least MIN_SGBM_PX)
#: make the check inconclusive rather than a verdict.
MIN_PIXELS = 500
MIN_SGBM_PX = 1.0
_NICE = (1, 2, 3, 4, 5, 8, 10, 16, 32, 64, 100, 128, 256, 512, 1000)


@dataclass(frozen=True)
class ScaleCheck:
    """Result of comparing a reference with SGBM on one or more frames.

    ``ratio``: median reference / SGBM (NaN when inconclusive). ``ok``: True within
    :data:`RATIO_TOLERANCE`, False when flagged, None when inconclusive.
    ``suggested_scale``: the ``--scale`` that would make the ratio about 1.
    """

    ok: bool | None
    ratio: float
    pixels: int
    frames: tuple[str, ...]
    scale: float
    suggested_scale: float | None
    reason: str

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["frames"] = list(self.frames)
        d["ratio"] = None if not math.isfinite(self.ratio) else round(self.ratio, 4)
        return d


def _round_up16(x: float) -> int:
    return int(16 * math.ceil(max(x, 16.0) / 16.0))


def search_range(reference: np.ndarray, width: int) -> int:
    """SGBM num_disparities that covers both the reference's range and a quarter of the
    width, so SGBM finds the true disparity whether the reference is too large or too small."""
    valid = reference[np.isfinite(reference) & (reference > 0)]
    top = float(np.percentile(valid, 99)) * 1.25 if valid.size else 0.0
    spec = SPEC_BY_KEY["sgbm.num_disparities"]
    # SGBM needs num_disparities + block_size < width to match anything at all.
    widest = int(min(spec.hi, 16 * ((width - 16) // 16)))
    return max(int(spec.lo), min(_round_up16(max(top, width / 4.0)), widest))


def frame_ratio(left: np.ndarray, right: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, int]:
    """Per-pixel reference / SGBM where both answer, and the num_disparities used."""
    nd = search_range(reference, left.shape[1])
    # Left matcher only, stricter uniqueness: we want pixels SGBM is sure of, not a filled map.
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": nd, "sgbm.uniqueness_ratio": 15,
                                       "wls.enabled": False})
    sgbm = DisparityPipeline(params).run(left, right).measured
    sel = np.isfinite(reference) & np.isfinite(sgbm) & (sgbm >= MIN_SGBM_PX) & (reference != 0)
    return (reference[sel] / sgbm[sel]).astype(np.float64), nd


def nice_scale(x: float) -> float:
    """``x`` snapped to a common scale factor (n or 1/n) when within 10 %, else 3 significant digits."""
    for n in _NICE:
        for cand in (float(n), 1.0 / n):
            if abs(x / cand - 1.0) < 0.10:
                return cand
    return float(f"{x:.3g}")


def check_reference_scale(samples: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
                          scale: float = 1.0, tolerance: float = RATIO_TOLERANCE) -> ScaleCheck:
    """Compare references with SGBM on sample frames.

    ``samples``: (frame key, left, right, reference) with uint8 images and an
    (H, W) float32 reference in px. ``scale``: the scale the references were read
    with (for the suggestion).
    """
    ratios = []
    keys = tuple(s[0] for s in samples)
    negative = 0
    positive = 0
    for _, left, right, ref in samples:
        finite = ref[np.isfinite(ref)]
        negative += int(np.count_nonzero(finite < 0))
        positive += int(np.count_nonzero(finite > 0))
        r, _ = frame_ratio(left, right, ref)
        ratios.append(r)
    if negative > positive:
        return ScaleCheck(False, math.nan, 0, keys, scale, None,
                          "most reference values are negative: disparity of the left image must be positive "
                          "(is it x-flow, or the right image's disparity?)")
    pooled = np.concatenate(ratios) if ratios else np.zeros(0)
    pooled = pooled[pooled > 0]
    if pooled.size < MIN_PIXELS:
        return ScaleCheck(None, math.nan, int(pooled.size), keys, scale, None,
                          f"inconclusive: only {pooled.size} pixels where SGBM and the reference both answer "
                          f"(need {MIN_PIXELS})")
    ratio = float(np.median(pooled))
    if 1.0 / tolerance < ratio < tolerance:
        return ScaleCheck(True, ratio, int(pooled.size), keys, scale, None,
                          f"reference / SGBM median ratio {ratio:.3f} over {pooled.size} pixels")
    suggested = nice_scale(scale * ratio)
    return ScaleCheck(False, ratio, int(pooled.size), keys, scale, suggested,
                      f"reference disparities are {ratio:.2f}x SGBM's (median over {pooled.size} pixels of "
                      f"{', '.join(keys)}; expected about 1): the scale looks wrong, try --scale {suggested:g}")
