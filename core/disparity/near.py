"""Near check: is something in the region nearer than the disparity search can match?

SGBM searches disparities up to ``min_disparity + num_disparities - 1`` (matched
px). An object nearer than the minimum range this sets has a larger disparity,
and SGBM then matches it to something else inside the search, i.e. *farther*
(issue 11: branches at 0.12-0.26 m came back as 0.28-0.49 m). The **near pass**
tells such a frame apart: the same SGBM on the region at a coarse scale (16 / d_max,
at least 0.125) searching 48 matched px from just before the main search's largest disparity
(to about four times it); pixels it matches confidently beyond the main search are
direct evidence of a nearer object.

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

from uav_depth.core.params import StereoParams

#: The near pass's search: 48 matched px from the main search's end, at a scale putting that end near 16.
NEAR_MIN_DISPARITY = 16
NEAR_NUM_DISPARITIES = 48
NEAR_MIN_SCALE = 0.125
#: The near search starts this many matched px before the main search's end, so that an object just
#: inside the main search is measured there and not piled at the near search's first disparity.
NEAR_OVERLAP = 4


@dataclass(frozen=True)
class NearCheck:
    """The near check of one frame.

    ``disparity``: (H, W) float32 disparity px (input resolution) the near pass
    measured, NaN where it matched nothing (its confidence is
    ``DisparityResult.near_confidence``); ranging looks at the pixels beyond
    ``max_disparity_px``, the main search's largest disparity, input px.
    """

    disparity: np.ndarray
    max_disparity_px: float
    #: ``textured()``: (H, W) bool, both views textured here at the near pass's scale (:func:`textured`),
    #: False outside the near pass's region; computed when first asked for (ranging asks only for a frame
    #: that is otherwise blank). None when not available.
    textured: Callable[[], np.ndarray] | None = None


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
    px (not below ``compute.scale``'s lower bound 0.125), searching 48 disparities from that end."""
    d_max = max_disparity_px(params)
    scale = max(NEAR_MIN_SCALE, min(params.compute.scale, NEAR_MIN_DISPARITY / d_max))
    # Grey 3x3 blocks with OpenCV's penalties for them (8 and 32 x channels x block area): at this
    # coarse scale a wider block smooths the near object into its background.
    return params.replace(**{"compute.scale": scale, "compute.grey": True,
                             "sgbm.min_disparity": max(0, int(math.floor(d_max * scale)) - NEAR_OVERLAP),
                             "sgbm.num_disparities": NEAR_NUM_DISPARITIES,
                             "sgbm.block_size": 3, "sgbm.p1": 72, "sgbm.p2": 288})
