"""Disparity quality metrics: the tuner's fitness and the evaluation reports.

Conventions (one place):
- Reference pixels that are NaN, inf or <= 0 are unknown and ignored.
- Estimate pixels that are NaN or inf count as disparity 0, never skipped: a
  matcher that answers nothing must not score best.
- PSNR's peak is the reference's largest valid disparity; SSIM's data_range is
  the same peak.
- SSIM is scikit-image's structural_similarity map (7x7 uniform window), with
  reference-unknown pixels of the reference replaced by the estimate there, then
  averaged over reference-valid pixels away from the border that scikit-image
  crops (3 px). With a fully valid reference it equals scikit-image's mean SSIM.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from uav_depth.core.errors import FrameError

try:
    from skimage.metrics import structural_similarity
except ImportError:  # pragma: no cover - exercised only without the tuning extra
    structural_similarity = None

SSIM_WIN = 7
METRIC_NAMES = ("mse", "psnr", "ssim", "bad1", "bad2", "valid")
#: Direction of each metric: +1 larger is better, -1 smaller is better.
DIRECTION = {"mse": -1, "psnr": +1, "ssim": +1, "bad1": -1, "bad2": -1, "valid": +1}


@dataclass(frozen=True)
class Scores:
    mse: float
    psnr: float
    ssim: float
    bad1: float     # % of reference-valid pixels off by more than 1 px
    bad2: float     # % off by more than 2 px
    valid: float    # fraction of reference-valid pixels the estimate answered

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


Box = tuple[int, int, int, int]


def in_box(box: Box | None, *maps: np.ndarray) -> tuple[np.ndarray, ...]:
    """The maps cut to ``box`` = (x0, y0, x1, y1), x1/y1 exclusive (None: whole maps).

    Scorers pass ``params.compute.roi_pixels(w, h)``: a pipeline that computes only its
    region answers nothing outside it by design, and that is not an error to score.
    """
    if box is None:
        return maps
    x0, y0, x1, y1 = box
    return tuple(m[y0:y1, x0:x1] for m in maps)


def reference_valid(ref: np.ndarray) -> np.ndarray:
    return np.isfinite(ref) & (ref > 0)


def _prepare(reference: np.ndarray, estimate: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ref = np.asarray(reference, dtype=np.float64)
    est = np.asarray(estimate, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 2:
        raise FrameError(f"reference {ref.shape} and estimate {est.shape} must be the same 2-D shape")
    valid = reference_valid(ref)
    if not valid.any():
        raise FrameError("reference has no valid pixel")
    est_filled = np.where(np.isfinite(est), est, 0.0)
    return ref, est_filled, valid


def mse(reference: np.ndarray, estimate: np.ndarray) -> float:
    ref, est, valid = _prepare(reference, estimate)
    return float(np.mean((est[valid] - ref[valid]) ** 2))


def peak(reference: np.ndarray) -> float:
    ref = np.asarray(reference, dtype=np.float64)
    return float(ref[reference_valid(ref)].max())


def psnr(reference: np.ndarray, estimate: np.ndarray) -> float:
    err = mse(reference, estimate)
    top = peak(reference)
    return math.inf if err == 0 else float(10.0 * math.log10(top * top / err))


def ssim(reference: np.ndarray, estimate: np.ndarray) -> float:
    if structural_similarity is None:
        from uav_depth.core.errors import DependencyError
        raise DependencyError("skimage", "tuning", "the SSIM metric")
    ref, est, valid = _prepare(reference, estimate)
    filled_ref = np.where(valid, ref, est)
    _, smap = structural_similarity(filled_ref, est, win_size=SSIM_WIN, data_range=peak(ref), full=True)
    pad = (SSIM_WIN - 1) // 2
    inner = np.zeros_like(valid)
    inner[pad:-pad, pad:-pad] = True
    sel = valid & inner
    return float(smap[sel].mean()) if sel.any() else float(smap[valid].mean())


def bad(reference: np.ndarray, estimate: np.ndarray, threshold: float) -> float:
    ref, est, valid = _prepare(reference, estimate)
    return float(100.0 * np.mean(np.abs(est[valid] - ref[valid]) > threshold))


def valid_fraction(reference: np.ndarray, estimate: np.ndarray) -> float:
    valid = reference_valid(np.asarray(reference, dtype=np.float64))
    return float(np.isfinite(np.asarray(estimate)[valid]).mean()) if valid.any() else 0.0


def score(reference: np.ndarray, estimate: np.ndarray) -> Scores:
    """All metrics of ``estimate`` against ``reference`` (both (H, W) px)."""
    m = mse(reference, estimate)
    top = peak(reference)
    return Scores(
        mse=m,
        psnr=math.inf if m == 0 else float(10.0 * math.log10(top * top / m)),
        ssim=ssim(reference, estimate),
        bad1=bad(reference, estimate, 1.0),
        bad2=bad(reference, estimate, 2.0),
        valid=valid_fraction(reference, estimate),
    )


METRICS = {"mse": mse, "psnr": psnr, "ssim": ssim}


# -- branch-aware: the number the drone uses ---------------------------------------------------------------------

#: Error charged to a frame whose branch distance could not be measured, %; also the cap of one frame's error.
BRANCH_MISS_PCT = 100.0


def branch_error(estimate_m: float | None, truth_m: float) -> float:
    """Relative branch-distance error in %, capped at BRANCH_MISS_PCT; no measurement costs BRANCH_MISS_PCT."""
    if estimate_m is None or not math.isfinite(estimate_m):
        return BRANCH_MISS_PCT
    return float(min(abs(estimate_m - truth_m) / truth_m * 100.0, BRANCH_MISS_PCT))
