"""Near check: is something in the region nearer than the disparity search can match?

SGBM searches disparities up to ``min_disparity + num_disparities - 1`` (matched
px). An object nearer than the minimum range this sets has a larger disparity,
and SGBM then matches it to something else inside the search, i.e. *farther*
(a branch at 0.2 m reads as one at 0.35 m, docs/ranging.md, *Too close*). The **near pass**
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

Ranging (``uav_depth.core.ranging``) decides "too close" from it.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from uav_depth.core.disparity.matching import MatchStage, upsample
from uav_depth.core.disparity.prepare import Prepared, check_pair, grey
from uav_depth.core.disparity.result import DisparityResult, Laps, NearCheck
from uav_depth.core.disparity.window import Window, margins, window
from uav_depth.core.params import StereoParams

#: The near pass's scale puts the main search's end near this many matched px (not below NEAR_MIN_SCALE) ...
NEAR_MIN_DISPARITY = 16
NEAR_MIN_SCALE = 0.125
#: ... and its search, from 0, reaches at least this many matched px past that end (rounded up to SGBM's
#: multiple of 16): 64 disparities for the flight file and the manual baseline, about 4 x the main search.
NEAR_BEYOND = 44
#: The near pass's match filters, whatever the main parameters say: the values its rules (ranging's too-close
#: rules 1, 3 and 4) were measured with, those of both shipped files and of OpenCV's sample. The near pass is a
#: safety check, not a tuned stage: ``uav-depth tune`` searches these keys for the main pass, and tuned filters
#: (speckle window 2670 / range 6, uniqueness 0) erase the near pass's matches and send branches inside the
#: minimum range as farther distances (docs/ranging.md, *Too close*).
NEAR_FILTERS = {"sgbm.uniqueness_ratio": 10, "sgbm.disp12_max_diff": 1, "sgbm.pre_filter_cap": 63,
                "sgbm.speckle_window_size": 100, "sgbm.speckle_range": 32}


#: A pixel is textured when its grey gradient (Sobel magnitude, 8-bit grey, at the near pass's coarse scale,
#: where the camera's noise is averaged over 8 x 8 input px) passes this in both views. Measured
#: (docs/ranging.md, *Too close*): a branch 5-8 cm from the lens left 1.8-53 % of the region textured in
#: both views, a sky-like ramp with noise of 8 grey levels (heavy gain) 0.1 %.
TEXTURE_GRADIENT = 12.0


def textured_view(view_m: np.ndarray) -> np.ndarray:
    """bool map of one view of the near pass's prepared (grey, coarse) crop: True where it is textured."""
    g = view_m.astype(np.float32)
    return cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) > TEXTURE_GRADIENT


def textured(left_m: np.ndarray, right_m: np.ndarray) -> np.ndarray:
    """uint8 map of the near pass's prepared (grey, coarse) crop: 1 where both views are textured."""
    return (textured_view(left_m) & textured_view(right_m)).astype(np.uint8)


def left_textured(left_m: np.ndarray, right_m: np.ndarray) -> np.ndarray:
    """uint8 map of the near pass's prepared (grey, coarse) crop: 1 where the left view is textured. The left
    view is the one every match starts from: a thin object against a blank background is textured there,
    while its right view's pixels at the same place are the background's."""
    return textured_view(left_m).astype(np.uint8)


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
    largest disparity at a coarse scale, answers only part of the region on a frame narrower than about 3.75
    times that disparity, and nothing on a narrower one (docs/ranging.md, *Too close*). Padding the
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


class NearStage:
    """The near check as a stage of the flight pipeline: the near pass (:func:`near_params`) of one frame size,
    adding :class:`.result.NearCheck` to the main pass's result. Where its search does not fit beside the
    region (:func:`near_pad`), it matches the rows its window needs, grey, padded by a mirror each side; its
    maps are put back at the input's rows and columns."""

    def __init__(self, params: StereoParams):
        self.main_max_disparity_px = max_disparity_px(params)
        self.params = near_params(params)
        self._sizes: dict[tuple[int, int], tuple[slice | None, int, int, MatchStage]] = {}

    def run(self, left: np.ndarray, right: np.ndarray, result: DisparityResult) -> DisparityResult:
        """``result`` with the near check of this pair (``near``) and its time (``timings_ms["near"]``)."""
        laps = Laps()
        measured, confidence, consistent, tex = self.maps(left, right)
        check = NearCheck(measured, self.main_max_disparity_px, None if tex is None else tex[textured], confidence,
                          consistent, None if tex is None else tex[left_textured])
        laps.lap("near")
        return DisparityResult(result.disparity, result.measured, result.confidence, result.warning,
                               {**result.timings_ms, **laps.ms}, near=check, fine=result.fine,
                               lr_consistent=result.lr_consistent)

    def for_size(self, width: int, height: int) -> tuple[slice | None, int, int, MatchStage]:
        """(rows matched or None for the whole frame, columns padded left and right, the near pass's match stage)
        for a ``width`` x ``height`` frame (built once per size)."""
        if (width, height) not in self._sizes:
            pad_l, pad_r = near_pad(self.params, width, height)
            if not (pad_l or pad_r):
                self._sizes[(width, height)] = None, 0, 0, MatchStage(self.params, smooth=False, lazy_confidence=True)
            else:
                _, cy0, _, cy1 = window(self.params, width, height).crop
                x0, y0, x1, y1 = self.params.compute.roi_pixels(width, height)
                wp, hb = pad_l + width + pad_r, cy1 - cy0
                params = self.params.replace(**{"compute.roi": ((x0 + pad_l) / wp, (y0 - cy0) / hb,
                                                                (x1 + pad_l) / wp, (y1 - cy0) / hb)})
                assert params.compute.roi_pixels(wp, hb) == (x0 + pad_l, y0 - cy0, x1 + pad_l, y1 - cy0)
                self._sizes[(width, height)] = (slice(cy0, cy1), pad_l, pad_r,
                                                MatchStage(params, smooth=False, lazy_confidence=True))
        return self._sizes[(width, height)]

    def maps(self, left: np.ndarray, right: np.ndarray):
        """(measured, confidence, left-right check, textured), each (H, W) at the input's resolution
        (:class:`.result.DisparityResult`); confidence is a callable computed when first asked for
        (:class:`.result.NearCheck`), or None; textured maps :func:`textured` and :func:`left_textured` to
        such callables, or is None."""
        check_pair(left, right)
        h, w = left.shape[:2]
        rows, pad_l, pad_r, stage = self.for_size(w, h)
        if rows is None:
            got = stage.run(left, right)
            win, prep, conf = got.window, got.prepared, got.later_confidence
            tex = None if win is None or prep is None else {
                fn: functools.partial(_textured_map, win, prep, (h, w), fn) for fn in (textured, left_textured)}
            return (got.result.measured, None if conf is None else functools.cache(conf), got.result.lr_consistent,
                    tex)
        left, right = pad_views(grey(left[rows]), grey(right[rows]), pad_l, pad_r)
        got = stage.run(left, right)
        res, win, prep, later = got.result, got.window, got.prepared, got.later_confidence
        cols = slice(pad_l, pad_l + w)
        measured = _at_rows(res.measured[:, cols], rows, h, np.nan)
        # A match whose partner lies left of the image (in the mirror) is no match: only columns left of the
        # near search's end can have one.
        reach = min(w, math.ceil(max_disparity_px(self.params)) + 1)
        with np.errstate(invalid="ignore"):
            band = measured[rows, :reach]
            band[band > np.arange(reach, dtype=np.float32)] = np.nan
        conf = None if later is None else functools.cache(lambda: _at_rows(later()[:, cols], rows, h, 0.0))
        lr = None if res.lr_consistent is None else _at_rows(res.lr_consistent[:, cols], rows, h, False)
        tex = None if win is None or prep is None else {
            fn: functools.partial(_padded_textured_map, win, prep, left.shape[:2], fn, cols, rows, h)
            for fn in (textured, left_textured)}
        return measured, conf, lr, tex


def _at_rows(band: np.ndarray, rows: slice, height: int, fill) -> np.ndarray:
    """``band`` (the input's ``rows``) placed in a (``height``, W) map filled with ``fill`` elsewhere."""
    out = np.empty((height, band.shape[1]), band.dtype)
    out[:rows.start] = fill
    out[rows] = band
    out[rows.stop:] = fill
    return out


def _textured_map(win: Window, prep: Prepared, shape: tuple[int, int], fn=textured) -> np.ndarray:
    """(H, W) bool: ``fn`` (:func:`textured` or :func:`left_textured`) of a pass's prepared views, at input
    resolution under its region."""
    tex = np.zeros(shape, bool)
    tex[win.outer()] = upsample(win, fn, prep.left_m, prep.right_m, interpolation=cv2.INTER_NEAREST) > 0
    return tex


def _padded_textured_map(win: Window, prep: Prepared, shape: tuple[int, int], fn, cols: slice, rows: slice,
                         height: int) -> np.ndarray:
    """:func:`_textured_map` of the padded rows' pass, put back at the input's ``rows`` and ``cols``."""
    return _at_rows(_textured_map(win, prep, shape, fn)[:, cols], rows, height, False)
