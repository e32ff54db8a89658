"""Disparity quality metrics: the tuner's fitness and the evaluation reports.

Two conventions, named in every report (:data:`CONVENTIONS`):

``bench`` (the default for reports; :func:`bench_scores`), as Middlebury and the
KITTI devkit score a method:

- error only over pixels with ground truth (reference NaN, inf or <= 0 is
  unknown: occluded or not measured, so every scored pixel is non-occluded);
- holes in the estimate filled first as the KITTI devkit does
  (:func:`fill_background`: along the row, each gap takes the smaller, i.e. the
  background, of its two valid neighbours; the row's ends extend the nearest
  valid value), so answering fewer pixels is never rewarded; ``density``, the
  fraction of ground-truth pixels answered before the filling, is reported
  beside it;
- mae, rmse (px), bad1/bad2/bad4 (% of ground-truth pixels off by more than
  1/2/4 px), psnr against a fixed peak: the search range
  (min_disparity + num_disparities, px), the same for every frame and candidate;
- the left strip the parameters cannot change is left out: columns left of
  ``strip_px`` = the frame's largest ground-truth disparity (a left pixel there may
  see its match outside the right image). It depends on the frame only, so every
  candidate is scored on the same pixels.

``paper`` (Lin et al. 2025; :func:`score`), kept for the faithful mode:
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
#: The metric conventions a report can use; the first is the default.
CONVENTIONS = ("bench", "paper")
#: Metrics of each convention, in report order.
METRIC_NAMES = {"paper": ("mse", "psnr", "ssim", "bad1", "bad2", "valid"),
                "bench": ("mae", "rmse", "bad1", "bad2", "bad4", "psnr", "density")}
#: Direction of each metric: +1 larger is better, -1 smaller is better.
DIRECTION = {"mse": -1, "psnr": +1, "ssim": +1, "bad1": -1, "bad2": -1, "bad4": -1, "valid": +1, "mae": -1,
             "rmse": -1, "density": +1, "branch": -1, "branch_safe": -1, "farther": -1}


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


def psnr_db(mse_px2: float, peak_px: float) -> float:
    """PSNR in dB of a mean squared error against a peak (the one PSNR formula of the project)."""
    return math.inf if mse_px2 == 0 else float(10.0 * math.log10(peak_px * peak_px / mse_px2))


def psnr(reference: np.ndarray, estimate: np.ndarray) -> float:
    """The paper's PSNR: peak = the reference's largest valid disparity."""
    return psnr_db(mse(reference, estimate), peak(reference))


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
    """All metrics of ``estimate`` against ``reference`` (both (H, W) px), paper convention."""
    m = mse(reference, estimate)
    return Scores(
        mse=m,
        psnr=psnr_db(m, peak(reference)),
        ssim=ssim(reference, estimate),
        bad1=bad(reference, estimate, 1.0),
        bad2=bad(reference, estimate, 2.0),
        valid=valid_fraction(reference, estimate),
    )


METRICS = {"mse": mse, "psnr": psnr, "ssim": ssim}


# -- benchmark convention ----------------------------------------------------------------------------------------

def fill_background(estimate: np.ndarray) -> np.ndarray:
    """Holes (NaN/inf) filled as the KITTI devkit's ``interpolateBackground`` does, row by row.

    A gap between two valid pixels of a row takes the smaller of the two (the
    background: a hole next to an object edge is an occlusion of what lies behind);
    a gap at either end of a row takes the nearest valid value; a row with no
    valid pixel becomes 0. Returns a float64 copy.
    """
    est = np.asarray(estimate, dtype=np.float64)
    valid = np.isfinite(est)
    h, w = est.shape
    cols = np.arange(w)
    left_idx = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right_idx = np.minimum.accumulate(np.where(valid, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    left_v = np.where(left_idx >= 0, est[rows, np.clip(left_idx, 0, w - 1)], np.nan)
    right_v = np.where(right_idx < w, est[rows, np.clip(right_idx, 0, w - 1)], np.nan)
    both = np.isfinite(left_v) & np.isfinite(right_v)
    fill = np.where(both, np.minimum(left_v, right_v), np.where(np.isfinite(left_v), left_v, right_v))
    out = np.where(valid, est, fill)
    return np.where(np.isfinite(out), out, 0.0)


def strip_px(reference: np.ndarray) -> int:
    """Width of the left strip the bench convention leaves out: the largest ground-truth disparity, px."""
    ref = np.asarray(reference, dtype=np.float64)
    valid = reference_valid(ref)
    return int(math.ceil(ref[valid].max())) if valid.any() else 0


def bench_scores(reference: np.ndarray, estimate: np.ndarray, peak_px: float, strip: int = 0) -> dict[str, float]:
    """Benchmark-convention metrics (module docstring) of ``estimate`` against ``reference``, both (H, W) px.

    ``peak_px``: PSNR's fixed peak (the search range); ``strip``: columns left of it
    are not scored. Raises FrameError when no ground-truth pixel is left to score.
    """
    ref = np.asarray(reference, dtype=np.float64)
    est = np.asarray(estimate, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 2:
        raise FrameError(f"reference {ref.shape} and estimate {est.shape} must be the same 2-D shape")
    filled = fill_background(est)
    valid = reference_valid(ref)
    valid[:, :max(0, strip)] = False
    if not valid.any():
        raise FrameError("reference has no valid pixel right of the unmatchable strip")
    err = np.abs(filled[valid] - ref[valid])
    m = float(np.mean(err ** 2))
    return {"mae": float(err.mean()), "rmse": math.sqrt(m),
            "bad1": float(100.0 * np.mean(err > 1.0)), "bad2": float(100.0 * np.mean(err > 2.0)),
            "bad4": float(100.0 * np.mean(err > 4.0)), "psnr": psnr_db(m, peak_px),
            "density": float(np.isfinite(est[valid]).mean())}


# -- branch-aware: the number the drone uses ---------------------------------------------------------------------

#: Error charged to a frame whose branch distance could not be measured, %; also the cap of one frame's error.
BRANCH_MISS_PCT = 100.0


#: A reading farther than the truth by more than this (%) is *farther*: the unsafe direction. 2 % is the
#: tolerance docs/ranging.md reports against (its "farther > 2 %" columns); within it a reading is
#: as good as the matcher's sub-pixel noise allows, beyond it the drone is told there is room that is not there.
FARTHER_TOL_PCT = 2.0


def branch_signed(estimate_m: float | None, truth_m: float) -> float:
    """Signed branch-distance error in %: positive = read farther than the truth; NaN when nothing was measured."""
    if estimate_m is None or not math.isfinite(estimate_m):
        return math.nan
    return float((estimate_m - truth_m) / truth_m * 100.0)


def branch_error(estimate_m: float | None, truth_m: float) -> float:
    """Relative branch-distance error in %, symmetric, capped at BRANCH_MISS_PCT; no measurement costs BRANCH_MISS_PCT.

    The plain error, reported beside :func:`safe_branch_error` (which the flown fitnesses use)."""
    signed = branch_signed(estimate_m, truth_m)
    return BRANCH_MISS_PCT if math.isnan(signed) else float(min(abs(signed), BRANCH_MISS_PCT))


def is_farther(estimate_m: float | None, truth_m: float, tol_pct: float = FARTHER_TOL_PCT) -> bool:
    """True when a reading is farther than the truth by more than ``tol_pct`` % (a miss is not farther)."""
    return branch_signed(estimate_m, truth_m) > tol_pct


def safe_branch_error(estimate_m: float | None, truth_m: float) -> float:
    """The safety-weighted branch error in % (the flown fitnesses' and the reports' one definition).

    - nearer, or farther by at most FARTHER_TOL_PCT: the plain error (capped at BRANCH_MISS_PCT);
    - no measurement: BRANCH_MISS_PCT, as :func:`branch_error`;
    - farther by more than FARTHER_TOL_PCT: BRANCH_MISS_PCT + the error (capped at BRANCH_MISS_PCT), i.e.
      always more than a miss. A miss sends nothing and the flight controller knows it is blind (the wire
      contract); a farther reading tells it the branch is beyond where it is, so the tuner must never trade
      a miss for one. The overshoot added on top keeps a gradient: less far is less bad.
    """
    signed = branch_signed(estimate_m, truth_m)
    if math.isnan(signed):
        return BRANCH_MISS_PCT
    if signed > FARTHER_TOL_PCT:
        return BRANCH_MISS_PCT + float(min(signed, BRANCH_MISS_PCT))
    return float(min(abs(signed), BRANCH_MISS_PCT))
