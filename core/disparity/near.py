"""Near check: is something in the region nearer than the disparity search can match?

SGBM searches disparities up to ``min_disparity + num_disparities - 1`` (matched
px). An object nearer than the minimum range this sets has a larger disparity,
and SGBM then matches it to something else inside the search, i.e. *farther*
(issue 11: branches at 0.12-0.26 m came back as 0.28-0.49 m). The **near pass**
tells such a frame apart: the same SGBM on the region at a coarse scale (16 / d_max,
at least 0.125) searching every disparity from 0 to at least 44 matched px past the main search's
largest disparity (about four times it); pixels it matches beyond the main search, left-right
consistent, are direct evidence of a nearer object. It searches the main range too, so that a match beyond it must
win against the one inside it: on a background that repeats about a tile's width away (a fence, a
trellis, the renderer's tiles), a search of the near range alone finds the copy one period away
and calls it near.

Nearer still (a few centimetres) the object's other view lies outside the right
image and nothing can be matched at all: the region is blank in both passes,
though both views are textured (:func:`textured`). Ranging reports such a frame
too close; a blank frame without texture (sky, a bare wall, a covered lens) is
too close only right after a too-close one (docs/ranging.md), else no
measurement.

Ranging (``uav_depth.daemon.ranging``) decides "too close" from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from uav_depth.core.disparity.window import margins
from uav_depth.core.params import StereoParams

#: The near pass's scale puts the main search's end near this many matched px (not below NEAR_MIN_SCALE) ...
NEAR_MIN_DISPARITY = 16
NEAR_MIN_SCALE = 0.125
#: ... and its search, from 0, reaches at least this many matched px past that end (rounded up to SGBM's
#: multiple of 16): 64 disparities for the flight file and the manual baseline, about 4 x the main search.
NEAR_BEYOND = 44
#: The near pass's match filters, whatever the main parameters say: the values its rules (ranging's too-close
#: rules 1, 3 and 4) were measured with, those of both shipped files and of OpenCV's sample. The near pass is a
#: safety check, not a tuned stage: ``uav-depth tune`` searches these keys for the main pass, and a tuned file with
#: speckle window 2670 / range 6 and uniqueness 0 (a real-pairs tune, 2026-12-05) erased the near pass's matches
#: and sent branches at 0.27-0.29 m, inside its minimum range of 0.347 m, as 0.50-0.51 m (docs/ranging.md).
NEAR_FILTERS = {"sgbm.uniqueness_ratio": 10, "sgbm.disp12_max_diff": 1, "sgbm.pre_filter_cap": 63,
                "sgbm.speckle_window_size": 100, "sgbm.speckle_range": 32}


@dataclass(frozen=True)
class NearCheck:
    """The near check of one frame.

    ``disparity``: (H, W) float32 disparity px (input resolution) the near pass
    measured, NaN where it matched nothing (its left-right check is
    ``DisparityResult.near_consistent``); ranging looks at the pixels beyond
    ``max_disparity_px``, the main search's largest disparity, input px.
    """

    disparity: np.ndarray
    max_disparity_px: float
    #: ``textured()``: (H, W) bool, both views textured here at the near pass's scale (:func:`textured`),
    #: False outside the near pass's region; computed when first asked for (ranging asks only for a frame
    #: that is otherwise blank). None when not available.
    textured: Callable[[], np.ndarray] | None = None
    #: ``confidence()``: (H, W) float32 0..1, the near pass's confidence (layout of
    #: ``DisparityResult.confidence``), computed when first asked for: ranging asks only when the main pass
    #: has matched too little of the region (rule 4), and its depth-edge weights are most of the check's
    #: cost. None without the near pass's right matcher.
    confidence: Callable[[], np.ndarray] | None = None


#: A pixel is textured when its grey gradient (Sobel magnitude, 8-bit grey, at the near pass's coarse scale,
#: where the camera's noise is averaged over 8 x 8 input px) passes this in both views. Measured
#: (docs/ranging.md, *Too close*): a branch 5-8 cm from the lens left 1.8-53 % of the region textured in
#: both views, a sky-like ramp with noise of 8 grey levels (heavy gain) 0.1 %.
TEXTURE_GRADIENT = 12.0


def textured(left_m: np.ndarray, right_m: np.ndarray) -> np.ndarray:
    """uint8 map of the near pass's prepared (grey, coarse) crop: 1 where both views are textured."""
    def grad(g: np.ndarray) -> np.ndarray:
        g = g.astype(np.float32)
        return cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))

    return ((grad(left_m) > TEXTURE_GRADIENT) & (grad(right_m) > TEXTURE_GRADIENT)).astype(np.uint8)


def max_disparity_px(params: StereoParams) -> float:
    """Largest disparity the main search returns, input px."""
    sg = params.sgbm
    return (sg.min_disparity + sg.num_disparities - 1) / params.compute.scale


def near_params(params: StereoParams) -> StereoParams:
    """The near pass: the main parameters, grey, at the scale where the main search ends near 16 matched
    px (not below ``compute.scale``'s lower bound 0.125), searching from 0 to at least NEAR_BEYOND past that
    end (the module docstring says why from 0); its confidence at its own matched resolution
    (``compute.wls_at`` says where WLS would smooth the main map: with ``input`` at 1/8 scale the left-right
    tolerance was 0.19 px, and nearly every near match had confidence 0); its match filters
    :data:`NEAR_FILTERS`. From ``params`` come only its scale and search (set by the main search's end), its
    region and the SGBM mode (a speed setting)."""
    d_max = max_disparity_px(params)
    scale = max(NEAR_MIN_SCALE, min(params.compute.scale, NEAR_MIN_DISPARITY / d_max))
    # Grey 3x3 blocks with OpenCV's penalties for them (8 and 32 x channels x block area): at this
    # coarse scale a wider block smooths the near object into its background.
    return params.replace(**{"compute.scale": scale, "compute.grey": True, "compute.wls_at": "matched",
                             "sgbm.min_disparity": 0,
                             "sgbm.num_disparities": -(-(int(math.floor(d_max * scale)) + NEAR_BEYOND) // 16) * 16,
                             "sgbm.block_size": 3, "sgbm.p1": 72, "sgbm.p2": 288, **NEAR_FILTERS})


def near_pad(near: StereoParams, width: int, height: int) -> tuple[int, int]:
    """Input columns to add left and right of a ``width`` x ``height`` frame so that the near pass (``near``:
    :func:`near_params`) answers its whole region with the left-right check, (0, 0) when its window fits.

    SGBM answers a column only when the whole search lies inside the image left of it (and the right matcher
    only when it lies right of it), so the near pass, which searches up to about four times the main search's
    largest disparity at a coarse scale, answered only part of the region on a frame narrower than about 3.75
    times that disparity, and nothing on a narrower one (issue 11; docs/ranging.md, *Too close*). Padding the
    views (:func:`pad_views`) lets it search every column; a match whose partner lies in the padding is dropped.
    Rounded up to whole coarse pixels of 1 / scale input px when that is whole."""
    x0, _, x1, _ = near.compute.roi_pixels(width, height)
    need_l, need_r, _ = margins(near)
    pad_l, pad_r = max(0, need_l - x0), max(0, need_r - (width - x1))
    k = round(1.0 / near.compute.scale)
    if k > 1 and abs(k * near.compute.scale - 1.0) < 1e-9:
        pad_l, pad_r = -(-pad_l // k) * k, -(-pad_r // k) * k
    return pad_l, pad_r


def pad_views(left: np.ndarray, right: np.ndarray, pad_l: int, pad_r: int) -> tuple[np.ndarray, np.ndarray]:
    """``left`` and ``right`` with ``pad_l`` / ``pad_r`` columns each side, each view mirrored at its edges
    (OpenCV's BORDER_REFLECT_101). A mirror continues the image's texture, so blocks at the edge see no seam:
    padded with noise instead, Midd1's near pass matched 2-5 % of its region confidently to partners within 37 px
    of the edge, a false "too close" (docs/ranging.md). A match into the mirror is no match (the pipeline's
    near pass drops it)."""
    return tuple(cv2.copyMakeBorder(v, 0, 0, pad_l, pad_r, cv2.BORDER_REFLECT_101) for v in (left, right))
