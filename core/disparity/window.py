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
    left_cols: int | None = None

    @property
    def left_width(self) -> int:
        """Matched columns (from the crop's left) the left matcher needs: all but the right matcher's own
        margin right of the region (``left_cols``; the whole crop when None)."""
        return self.matched[0] if self.left_cols is None else self.left_cols

    @property
    def factor(self) -> int | None:
        """Input px per matched px when that is the same whole number along both axes (the fast resize
        paths, and the region's maps taken from a sub-block), else None."""
        (cw, ch), (mw, mh) = self.crop_size, self.matched
        k = cw // mw
        return k if k * mw == cw and k * mh == ch else None

    def inner_matched(self, margin: int = 0) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) matched px of the crop that cover the region, plus ``margin`` matched px each side
        (inside the matched crop). Only with a whole-number :attr:`factor`."""
        k = self.factor
        assert k is not None
        (ys, xs) = self.inner()
        mw, mh = self.matched
        return (max(0, xs.start // k - margin), max(0, ys.start // k - margin),
                min(mw, -(-xs.stop // k) + margin), min(mh, -(-ys.stop // k) + margin))

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


def context_px(params: StereoParams) -> int:
    """Matched px of real image kept around what is matched (:data:`CONTEXT_PX`, and half a block more): the
    window's region and the fine pass's box."""
    return max(CONTEXT_PX, params.sgbm.block_size // 2 + 1)


def margins(params: StereoParams) -> tuple[int, int, int]:
    """Input px of image a window wants left, right, and above and below the region (:func:`window`)."""
    sg, cp = params.sgbm, params.compute
    context = context_px(params)
    band = max(0, sg.min_disparity + sg.num_disparities)
    left = math.ceil((band + context) / cp.scale)
    right = math.ceil((max(0, -sg.min_disparity) + context + (band if params.wls.enabled else 0)) / cp.scale)
    return left, right, math.ceil(context / cp.scale)


def window(params: StereoParams, width: int, height: int) -> Window:
    """The crop that holds ``compute.roi`` plus the disparity search margin, and its matched size.

    A left pixel at x matches right pixels x - d for d in min_disparity ..
    min_disparity + num_disparities - 1 (matched pixels), so the crop reaches that
    far left of the region (and right of it for a negative min_disparity). With the
    right matcher on (``wls.enabled``: the left-right check) the crop also reaches
    min_disparity + num_disparities right of the region: the right matcher leaves
    that many columns at the crop's right edge unanswered, and a left pixel whose
    partner falls there is not left-right checked (:mod:`.confidence`); so every
    pixel of the region is, unless the image itself ends. The left matcher needs none of
    that right margin (``Window.left_cols``): its matches lie left of each pixel.

    Where ``1 / compute.scale`` is a whole number k, the crop is grown (outward, inside
    the image) to a multiple of k in both directions: the matched size is then exactly
    the crop over k, OpenCV resizes by its fast integer paths, and the region's maps
    are taken from the sub-block under it (:class:`DisparityPipeline`).
    """
    sg, cp = params.sgbm, params.compute
    rx0, ry0, rx1, ry1 = cp.roi_pixels(width, height)
    left, right, vert = margins(params)
    crop = (max(0, rx0 - left), max(0, ry0 - vert), min(width, rx1 + right), min(height, ry1 + vert))
    k = round(1.0 / cp.scale)
    if k > 1 and abs(k * cp.scale - 1.0) < 1e-9:
        x0, x1 = _grow(crop[0], crop[2], k, width)
        y0, y1 = _grow(crop[1], crop[3], k, height)
        crop = (x0, y0, x1, y1)
    cw, ch = crop[2] - crop[0], crop[3] - crop[1]
    matched = (max(1, round(cw * cp.scale)), max(1, round(ch * cp.scale)))
    left_cols = None
    if params.wls.enabled:
        # The left matcher's crop ends the left margin's mirror right of the region: context, no search band.
        lx1 = min(crop[2], rx1 + math.ceil((max(0, -sg.min_disparity) + context_px(params)) / cp.scale))
        left_cols = min(matched[0], math.ceil((lx1 - crop[0]) * matched[0] / cw))
    return Window(crop, (rx0, ry0, rx1, ry1), matched, left_cols)


def _grow(lo: int, hi: int, k: int, size: int) -> tuple[int, int]:
    """``lo..hi`` grown to a multiple of ``k`` long, rightward then leftward, inside ``0..size`` (as it is
    when the image itself is too small)."""
    need = -(hi - lo) % k
    more = min(need, size - hi)
    hi += more
    lo -= min(need - more, lo)
    return lo, hi
