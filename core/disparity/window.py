"""Window geometry: which part of the input is matched, at which size, to answer ``compute.roi``.

The full frame is a window like any other (its crop is the whole image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uav_depth.core.params import StereoParams

#: Rows and columns of real image matched around the region (in matched pixels, at
#: least this many and half a block more), so that blocks at the region's edge see
#: image, not OpenCV's replicated border, and the top-down pass has some run-in.
CONTEXT_PX = 4


@dataclass(frozen=True)
class Window:
    """Where a region is matched: the crop of the input and the region inside it (input px).

    ``crop`` and ``region``: (x0, y0, x1, y1) in the input image; ``matched``:
    (width, height) the crop is matched at; ``ratio``: input px per matched px along
    the baseline (disparities are multiplied by it); ``matchable``: False when the
    matched crop is not wider than the disparity search (SGBM could answer nothing).
    """

    crop: tuple[int, int, int, int]
    region: tuple[int, int, int, int]
    matched: tuple[int, int]

    @property
    def crop_size(self) -> tuple[int, int]:
        return self.crop[2] - self.crop[0], self.crop[3] - self.crop[1]

    @property
    def ratio(self) -> float:
        return self.crop_size[0] / self.matched[0]

    @property
    def resized(self) -> bool:
        return self.matched != self.crop_size

    def inner(self) -> tuple[slice, slice]:
        """The region as slices of the crop."""
        (cx0, cy0, _, _), (rx0, ry0, rx1, ry1) = self.crop, self.region
        return slice(ry0 - cy0, ry1 - cy0), slice(rx0 - cx0, rx1 - cx0)

    def outer(self) -> tuple[slice, slice]:
        """The region as slices of the input image."""
        rx0, ry0, rx1, ry1 = self.region
        return slice(ry0, ry1), slice(rx0, rx1)


def search_span(params: StereoParams) -> int:
    """Matched columns SGBM leaves unanswered at the crop's edges: left and right bands together."""
    sg = params.sgbm
    return max(0, sg.min_disparity + sg.num_disparities) + max(0, -sg.min_disparity)


def window(params: StereoParams, width: int, height: int) -> Window:
    """The crop that holds ``compute.roi`` plus the disparity search margin, and its matched size.

    A left pixel at x matches right pixels x - d for d in min_disparity ..
    min_disparity + num_disparities - 1 (matched pixels), so the crop reaches that
    far left of the region (and right of it for a negative min_disparity). With the
    right matcher on (``wls.enabled``: the left-right check) the crop also reaches
    min_disparity + num_disparities right of the region: the right matcher leaves
    that many columns at the crop's right edge unanswered, and a left pixel whose
    partner falls there is not left-right checked (:mod:`.confidence`); so every
    pixel of the region is, unless the image itself ends.
    """
    sg, cp = params.sgbm, params.compute
    rx0, ry0, rx1, ry1 = cp.roi_pixels(width, height)
    context = max(CONTEXT_PX, sg.block_size // 2 + 1)
    band = max(0, sg.min_disparity + sg.num_disparities)
    left = math.ceil((band + context) / cp.scale)
    right = math.ceil((max(0, -sg.min_disparity) + context + (band if params.wls.enabled else 0)) / cp.scale)
    vert = math.ceil(context / cp.scale)
    crop = (max(0, rx0 - left), max(0, ry0 - vert), min(width, rx1 + right), min(height, ry1 + vert))
    cw, ch = crop[2] - crop[0], crop[3] - crop[1]
    matched = (max(1, round(cw * cp.scale)), max(1, round(ch * cp.scale)))
    return Window(crop, (rx0, ry0, rx1, ry1), matched)
