"""A reference-free fitness: how well the left disparity explains the right image.

For frames with no reference disparity at all (fresh flight logs), the tuner can
score a disparity map by photometric reconstruction, as self-supervised stereo
and depth networks are trained (Godard et al., Monodepth, CVPR 2017; Monodepth2,
ICCV 2019): warp the right image by the left disparity and compare it with the
left image. Per pixel p of the left image, with images in 0..1 and costs in 0..1:

    photo(p)  = ALPHA * (1 - SSIM(p)) / 2 + (1 - ALPHA) * |I_l(p) - I_r(x - d(p), y)|
    smooth(p) = min(1, |dx d*| exp(-|dx I_l|) + |dy d*| exp(-|dy I_l|)),  d* = d / mean(d)
    cost(p)   = (photo(p) + W_SMOOTH * smooth(p)) / (1 + W_SMOOTH)

with ALPHA = 0.85 and a 3x3 SSIM window as in Monodepth, the edge-aware
smoothness of Monodepth2 on mean-normalised disparity, and W_SMOOTH (see below).
A pixel with no disparity (NaN), or whose match falls outside the right image,
costs the maximum, 1: a matcher that answers nothing scores 1.0, the worst
possible value, and never best. This invalid-pixel penalty stands in for the
left-right consistency term of Monodepth: the loss only sees the left map, and
SGBM's own disp12MaxDiff / WLS confidence already removed inconsistent pixels;
the penalty stops that removal from being free.

The loss is the mean cost over all pixels, in 0..1, lower is better. How far it
agrees with true error is measured in ``bench/selfsup_rank.py`` (README,
"References"): it ranks gross failures correctly; among good parameter sets it
is a coarse guide, not a replacement for a reference. It cannot see a wrong match
that reconstructs the image as well as the right one: repetitive texture matched
at the wrong period, textureless regions.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from uav_depth.core.disparity import check_pair
from uav_depth.core.errors import FrameError

from uav_depth.tuning.metrics import Box, in_box

#: SSIM vs L1 mix of the photometric term (Monodepth, Monodepth2).
ALPHA = 0.85
#: Weight of the edge-aware smoothness term against the photometric term (Monodepth2
#: uses 1e-3). Measured with bench/selfsup_rank.py: weights 0..0.1 change the rank
#: correlation with true error by less than 0.01; 1.0 lowers it against bad-2 (0.91 ->
#: 0.86 on the motorcycle pair, 0.88 -> 0.81 on synthetic 1280x720 frames). 0.01 keeps
#: the term as a tie-breaker without letting it outvote the photometric evidence.
W_SMOOTH = 0.01
#: Cost of a pixel without a usable disparity: the maximum of photo and smooth.
INVALID_COST = 1.0
_SSIM_C1 = 0.01 ** 2
_SSIM_C2 = 0.03 ** 2


@dataclass(frozen=True)
class SelfsupTerms:
    """The parts of :func:`selfsup_loss` for one frame.

    ``photo``/``smooth``: mean over pixels with a usable disparity (NaN if none).
    ``usable``: fraction of pixels with a disparity whose match is inside the right
    image. ``loss``: the combined value :func:`selfsup_loss` returns.
    """

    loss: float
    photo: float
    smooth: float
    usable: float


def _unit(img: np.ndarray) -> np.ndarray:
    """uint8 (H, W) or (H, W, 3) -> float32 (H, W, C) in 0..1."""
    x = img.astype(np.float32) * np.float32(1.0 / 255.0)
    return x[..., None] if x.ndim == 2 else x


def _box(x: np.ndarray) -> np.ndarray:
    # 3x3 mean with reflection at the border, as Monodepth's SSIM (AvgPool2d(3, 1) after ReflectionPad2d(1)).
    return cv2.blur(x, (3, 3), borderType=cv2.BORDER_REFLECT_101)


def _dssim(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel (1 - SSIM) / 2 in 0..1, averaged over channels; a, b (H, W, C) float32."""
    mu_a, mu_b = _box(a), _box(b)
    var_a = _box(a * a) - mu_a * mu_a
    var_b = _box(b * b) - mu_b * mu_b
    cov = _box(a * b) - mu_a * mu_b
    num = (2 * mu_a * mu_b + _SSIM_C1) * (2 * cov + _SSIM_C2)
    den = (mu_a * mu_a + mu_b * mu_b + _SSIM_C1) * (var_a + var_b + _SSIM_C2)
    d = np.clip((1.0 - num / den) * 0.5, 0.0, 1.0)
    return d.mean(axis=2) if d.ndim == 3 else d


def selfsup_terms(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                  box: Box | None = None) -> SelfsupTerms:
    """The reference-free loss and its parts; see :func:`selfsup_loss`."""
    check_pair(left, right)
    h, w = left.shape[:2]
    disp = np.asarray(disparity, dtype=np.float32)
    if disp.shape != (h, w):
        raise FrameError(f"disparity must be (H, W) = {(h, w)} like the images, but got shape {disp.shape}")
    il, ir = _unit(left), _unit(right)
    valid = np.isfinite(disp)
    xs = np.arange(w, dtype=np.float32)[None, :] - np.where(valid, disp, 0.0)
    # Bilinear sampling needs both neighbours inside the image.
    usable = valid & (xs >= 0.0) & (xs <= w - 1)
    map_x = np.where(usable, xs, -1.0).astype(np.float32)
    map_y = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w)).copy()
    warped = cv2.remap(ir, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if warped.ndim == 2:
        warped = warped[..., None]
    # Unusable pixels take the left value so they do not add error to their valid neighbours' SSIM windows;
    # they pay INVALID_COST themselves.
    warped = np.where(usable[..., None], warped, il)
    photo = ALPHA * _dssim(il, warped) + (1.0 - ALPHA) * np.abs(il - warped).mean(axis=2)

    smooth = _edge_aware_smoothness(il, disp, valid)
    cost = (photo + W_SMOOTH * smooth) / (1.0 + W_SMOOTH)
    cost = np.where(usable, cost, INVALID_COST)
    # Warping above used the whole right image; only the scored region counts.
    cost, photo, smooth, usable = in_box(box, cost, photo, smooth, usable)
    n = int(usable.sum())
    return SelfsupTerms(
        loss=float(cost.mean()),
        photo=float(photo[usable].mean()) if n else float("nan"),
        smooth=float(smooth[usable].mean()) if n else float("nan"),
        usable=n / float(usable.size),
    )


def _edge_aware_smoothness(img: np.ndarray, disp: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per-pixel Monodepth2 smoothness of mean-normalised disparity, clipped to 0..1.

    Only pairs of neighbouring pixels that both have a disparity contribute; the
    forward difference of pixel p is charged to p.
    """
    h, w = disp.shape
    out = np.zeros((h, w), np.float32)
    if not valid.any():
        return out
    mean = float(np.abs(disp[valid]).mean())
    d = np.where(valid, disp, 0.0) / np.float32(max(mean, 1e-6))
    gray = img.mean(axis=2)
    dx = np.abs(d[:, 1:] - d[:, :-1]) * np.exp(-np.abs(gray[:, 1:] - gray[:, :-1]))
    dy = np.abs(d[1:, :] - d[:-1, :]) * np.exp(-np.abs(gray[1:, :] - gray[:-1, :]))
    out[:, :-1] += np.where(valid[:, 1:] & valid[:, :-1], dx, 0.0)
    out[:-1, :] += np.where(valid[1:, :] & valid[:-1, :], dy, 0.0)
    return np.minimum(out, 1.0)


def selfsup_loss(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                 box: Box | None = None) -> float:
    """Reference-free loss of a left disparity map, in 0..1, lower is better.

    ``left``/``right``: rectified uint8 grey (H, W) or BGR (H, W, 3) images.
    ``disparity``: (H, W) float32 disparity in px of the left image, NaN invalid
    (as :meth:`DisparityPipeline.compute` returns). An all-NaN map scores 1.0.
    ``box``: (x0, y0, x1, y1) to score only that region (the pipeline's ``compute.roi``);
    the warp still reads the whole right image.
    """
    return selfsup_terms(left, right, disparity, box).loss
