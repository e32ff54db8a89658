"""The disparity stage: OpenCV SGBM, a right matcher, a left-right confidence and (optionally) WLS.

This is the one disparity path of the project: the daemon flies it and the tuner
scores it. Build :class:`DisparityPipeline` from validated :class:`StereoParams`;
``run`` maps a rectified pair to a :class:`DisparityResult` of (H, W) float32 maps
at the input's resolution. The modules follow the stages, each a small function
of frozen inputs:

* :mod:`.window`: which crop of the input answers ``compute.roi`` (the full
  frame is a window like any other) and at which matched size;
* :mod:`.prepare`: check the pair, crop, grey (``compute.grey``), resize
  (``compute.scale``);
* :mod:`.match`: the left SGBM and, when ``wls.enabled``, the right one;
* :mod:`.confidence`: the left-right confidence (OpenCV's WLS definition);
* refine: OpenCV's WLS smoothing at the input or matched resolution
  (``compute.wls_at``), only when the pipeline is built with ``refine=True``
  (the daemon ranges on ``measured`` + ``confidence`` and builds it without);
* assemble (here): paste the region into full-size maps, disparities in input px;
* near (:mod:`.near`) and fine (:mod:`.fine`), in the flight pipeline: a coarse pass
  for objects nearer than the search, and a full-resolution re-match of the box
  ranging asks for (``DisparityResult.fine``).

Outside the region disparities are NaN and confidence is 0. With the default
parameters the pipeline computes exactly OpenCV's sample (full frame, full
resolution, colour as given).
"""

from __future__ import annotations

from dataclasses import replace

import functools
import math
import warnings
from typing import Callable

import cv2
import numpy as np

from uav_depth.core.disparity.confidence import confidence_maps
from uav_depth.core.disparity.fine import FineMatch, FineMatcher
from uav_depth.core.disparity.near import NearCheck, max_disparity_px, near_params, near_pad, pad_views, textured
from uav_depth.core.disparity.match import Matchers, build_matchers, match_left, match_right, to_float
from uav_depth.core.disparity.prepare import Prepared, check_pair, grey, prepare
from uav_depth.core.disparity.result import DisparityResult, Laps
from uav_depth.core.disparity.window import Window, search_span, window
from uav_depth.core.errors import ParameterWarning
from uav_depth.core.params import OPENCV_COST_MAX, StereoParams


class DisparityPipeline:
    """The stages built once from validated parameters.

    ``refine``: run WLS's smoothing for ``DisparityResult.disparity`` (when
    ``wls.enabled``); without it ``disparity`` holds the measured values and the
    run skips the smoothing's cost. ``measured`` and ``confidence`` do not depend
    on it. Not thread-safe (OpenCV matcher objects keep state): build one per
    thread or process. Building is cheap (well under a millisecond).

    ``lazy_confidence`` (the near pass's own pipeline): ``_run`` computes the left-right check and leaves the
    confidence's depth-edge weights, most of its cost, to a callable it returns beside the result.
    """

    def __init__(self, params: StereoParams, refine: bool = True, near: bool = False, fine: bool = False,
                 lazy_confidence: bool = False):
        self.params = params
        self.refine = refine and params.wls.enabled
        self._lazy_confidence = lazy_confidence
        self._near = _NearPass(params) if near else None
        # The fine pass only adds resolution: at compute.scale 1 the main match is already full resolution.
        self._fine = FineMatcher(params) if fine and params.compute.fine_pass else None
        self.matchers: Matchers = build_matchers(params)
        m = self.matchers
        self.left_matcher, self.right_matcher, self.wls = m.left, m.right, m.wls
        sg = params.sgbm
        self._overflow = None
        if sg.overflows:
            self._overflow = (f"sgbm.p1={sg.p1}/sgbm.p2={sg.p2} exceed OpenCV's 16-bit cost limit "
                              f"{OPENCV_COST_MAX}: no disparity computed")

    def run(self, left: np.ndarray, right: np.ndarray) -> DisparityResult:
        """Disparity of a rectified pair (uint8 grey or BGR colour, same shape).

        Every map is (H, W) at the input's resolution whatever ``compute.*`` says;
        outside ``compute.roi`` disparities are NaN and confidence is 0. A window
        too narrow for the disparity search gives all-NaN maps (nothing matched).
        """
        res, _, _, _ = self._run(left, right)
        fine = None if self._fine is None or res.warning else functools.partial(self._fine.match, left, right)
        if self._near is None:
            return res if fine is None else replace(res, fine=fine)
        laps = Laps()
        near_measured, near_confidence, near_consistent, tex = self._near.run(left, right)
        check = NearCheck(near_measured, max_disparity_px(self.params), tex, near_confidence)
        laps.lap("near")
        return DisparityResult(res.disparity, res.measured, res.confidence, res.warning,
                               {**res.timings_ms, **laps.ms}, near=check, near_consistent=near_consistent,
                               fine=fine, lr_consistent=res.lr_consistent)

    def _run(self, left: np.ndarray, right: np.ndarray) -> tuple[DisparityResult, Window | None, Prepared | None,
                                                                 Callable[[], np.ndarray] | None]:
        """One pass of the stages; also the window and prepared images (None when nothing was matched) and,
        with ``lazy_confidence``, a callable that computes the confidence map the result leaves None (else
        None)."""
        laps = Laps()
        check_pair(left, right)
        h, w = left.shape[:2]
        if self._overflow is not None:
            warnings.warn(self._overflow, ParameterWarning, stacklevel=2)
            empty = np.full((h, w), np.nan, np.float32)
            return DisparityResult(empty, empty.copy(), None, self._overflow), None, None, None
        win = window(self.params, w, h)
        # With lazy_confidence the map is made when asked for (:meth:`_confidence_map`), not here.
        conf_full = None if self.right_matcher is None or self._lazy_confidence else np.zeros((h, w), np.float32)
        measured = np.full((h, w), np.nan, np.float32)
        if win.matched[0] <= search_span(self.params):    # narrower than the search: nothing can be matched
            laps.lap("prepare")
            return DisparityResult(np.full((h, w), np.nan, np.float32), measured, conf_full,
                                   timings_ms=laps.ms), None, None, None
        prep = prepare(self.params.compute, win, left, right)
        laps.lap("prepare")
        left16 = self._match_left(win, prep)
        laps.lap("match_left")
        measured[win.outer()] = self._measured(win, left16)
        if self.right_matcher is None:
            laps.lap("assemble")
            return DisparityResult(measured, measured, None, timings_ms=laps.ms), win, prep, None
        right16 = match_right(self.matchers, prep.left_m, prep.right_m)
        laps.lap("match_right")
        conf, lr = self._confidence(win, left16, right16, weights=not self._lazy_confidence)
        later = None
        if conf is None:
            later = functools.partial(self._confidence_map, win, left16, right16, (h, w))
        else:
            _place_confidence(conf_full, win, conf)
        lr_full = np.zeros((h, w), bool)
        lr_full[win.outer()] = lr > 0
        laps.lap("confidence")
        if not self.refine:
            laps.lap("assemble")
            return (DisparityResult(measured, measured, conf_full, timings_ms=laps.ms, lr_consistent=lr_full),
                    win, prep, later)
        filt = self._refine(win, prep, left16, right16)
        laps.lap("wls")
        disparity = np.full((h, w), np.nan, np.float32)
        disparity[win.outer()] = filt[win.inner()]
        laps.lap("assemble")
        return (DisparityResult(disparity, measured, conf_full, timings_ms=laps.ms, lr_consistent=lr_full),
                win, prep, later)

    def _match_left(self, win: Window, prep: Prepared) -> np.ndarray:
        """The left matcher over the columns it needs (:attr:`Window.left_width`), at the crop's matched
        width: the columns right of them hold OpenCV's invalid value. With the WLS smoothing on
        (``refine``), over the whole crop, as before: the smoothing spreads what it is given into the
        region, so those columns' real matches keep its map unchanged (the tuner's faithful mode). The
        region's measured pixels differ between the two by SGBM's right-to-left path alone (under 1 % by
        more than 1 px, tested)."""
        lw = win.left_width
        if self.refine or lw >= win.matched[0] or lw <= search_span(self.params):
            return match_left(self.matchers, prep.left_m, prep.right_m)
        part = match_left(self.matchers, np.ascontiguousarray(prep.left_m[:, :lw]),
                          np.ascontiguousarray(prep.right_m[:, :lw]))
        left16 = np.full((part.shape[0], win.matched[0]), (self.params.sgbm.min_disparity - 1) * 16, np.int16)
        left16[:, :lw] = part
        return left16

    def _measured(self, win: Window, left16: np.ndarray) -> np.ndarray:
        """The left matcher's disparities under the region, input px."""
        min_d = self.params.sgbm.min_disparity
        if not win.resized:
            return to_float(left16[win.inner()], min_d)
        # Nearest, not linear: a measured value is one pixel's match, never a blend with NaN.
        return _upsample(win, to_float, left16, min_d, win.ratio, interpolation=cv2.INTER_NEAREST)

    def _wls_at_matched(self, win: Window) -> bool:
        return self.params.compute.wls_at == "matched" or not win.resized

    def _confidence_map(self, win: Window, left16: np.ndarray, right16: np.ndarray,
                        shape: tuple[int, int]) -> np.ndarray:
        """The (H, W) 0..1 confidence map of a run (``lazy_confidence``: computed when asked for)."""
        full = np.zeros(shape, np.float32)
        _place_confidence(full, win, self._confidence(win, left16, right16)[0])
        return full

    def _confidence(self, win: Window, left16: np.ndarray, right16: np.ndarray,
                    weights: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        """0..255 confidence under the region, as WLS computes it for the guide it would be given, and the
        left-right check alone (uint8 0/1, :func:`.confidence.confidence_maps`); ``weights=False``: the
        check alone, (None, check)."""
        # WLS given the full-resolution guide scales its threshold and roll-off by the width ratio.
        rf = 1.0 if self._wls_at_matched(win) else float(np.float32(win.matched[0]) / np.float32(win.crop_size[0]))
        sg = self.params.sgbm
        if not win.resized:
            ys, xs = win.inner()
            conf, lr = confidence_maps(left16, right16, sg, rf, cols=(xs.start, xs.stop), weights=weights)
            return None if conf is None else conf[ys, xs], lr[ys, xs]
        if win.factor is None:
            conf, lr = confidence_maps(left16, right16, sg, rf, weights=weights)
            up = None if conf is None else cv2.resize(conf, win.crop_size, interpolation=cv2.INTER_LINEAR)
            return (None if up is None else up[win.inner()],
                    cv2.resize(lr, win.crop_size, interpolation=cv2.INTER_NEAREST)[win.inner()])
        # Linear: one matched pixel more each side, so that the sub-block's border is never interpolated.
        # The check alone: nearest, as the measured values it belongs to.
        x0, _, x1, _ = win.inner_matched(margin=1)
        conf, lr = confidence_maps(left16, right16, sg, rf, cols=(x0, x1), weights=weights)
        return (None if conf is None else _upsample(win, lambda: conf, interpolation=cv2.INTER_LINEAR, margin=1),
                _upsample(win, lambda: lr, interpolation=cv2.INTER_NEAREST, margin=1))

    def _refine(self, win: Window, prep: Prepared, left16: np.ndarray, right16: np.ndarray) -> np.ndarray:
        """WLS-smoothed disparity over the crop, input px, NaN where invalid."""
        min_d = self.params.sgbm.min_disparity
        assert self.wls is not None
        if win.resized and self.params.compute.wls_at == "matched":
            # WLS at the matched resolution (a quarter of the pixels at scale 0.5), then
            # resized: linear for the smooth filtered map (a NaN neighbour stays NaN).
            filtered16 = self.wls.filter(left16, prep.left_m, disparity_map_right=right16)
            return cv2.resize(to_float(filtered16, min_d, win.ratio), win.crop_size, interpolation=cv2.INTER_LINEAR)
        # Given the full-resolution guide, OpenCV's WLS upsamples the low-resolution
        # disparity itself (scaling values by the width ratio) and filters at full
        # resolution, so edges follow the real image.
        filtered16 = self.wls.filter(left16, prep.left, disparity_map_right=right16)
        filt = filtered16.astype(np.float32) * np.float32(1.0 / 16.0)
        # Below the smallest searched disparity (in input px) is invalid. OpenCV fills
        # what lies outside its valid band with 16*(min_disparity-1), unscaled: with a
        # negative min_disparity and upscaling that is not below the threshold.
        filt[(filtered16 < min_d * 16 * win.ratio) | (filtered16 == 16 * (min_d - 1))] = np.nan
        return filt

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(H, W) float32 disparity in px of the left image, NaN where invalid."""
        return self.run(left, right).disparity


class _NearPass:
    """The near pass (:func:`.near.near_params`) of one frame size. Where its search does not fit beside the region
    (:func:`.near.near_pad`), it matches the rows its window needs, grey, padded by a mirror each side; its maps
    are put back at the input's rows and columns."""

    def __init__(self, params: StereoParams):
        self.params = near_params(params)
        self._sizes: dict[tuple[int, int], tuple[slice | None, int, int, DisparityPipeline]] = {}

    def _for(self, width: int, height: int) -> tuple[slice | None, int, int, "DisparityPipeline"]:
        if (width, height) not in self._sizes:
            pad_l, pad_r = near_pad(self.params, width, height)
            if not (pad_l or pad_r):
                self._sizes[(width, height)] = None, 0, 0, DisparityPipeline(self.params, refine=False,
                                                                            lazy_confidence=True)
            else:
                _, cy0, _, cy1 = window(self.params, width, height).crop
                x0, y0, x1, y1 = self.params.compute.roi_pixels(width, height)
                wp, hb = pad_l + width + pad_r, cy1 - cy0
                params = self.params.replace(**{"compute.roi": ((x0 + pad_l) / wp, (y0 - cy0) / hb,
                                                                (x1 + pad_l) / wp, (y1 - cy0) / hb)})
                assert params.compute.roi_pixels(wp, hb) == (x0 + pad_l, y0 - cy0, x1 + pad_l, y1 - cy0)
                self._sizes[(width, height)] = (slice(cy0, cy1), pad_l, pad_r,
                                                DisparityPipeline(params, refine=False, lazy_confidence=True))
        return self._sizes[(width, height)]

    def run(self, left: np.ndarray, right: np.ndarray):
        """(measured, confidence, left-right check, textured), each (H, W) at the input's resolution
        (:class:`.result.DisparityResult`); confidence and textured are callables computed when first asked
        for (:class:`.near.NearCheck`), or None."""
        check_pair(left, right)
        h, w = left.shape[:2]
        rows, pad_l, pad_r, pipe = self._for(w, h)
        if rows is None:
            res, win, prep, conf = pipe._run(left, right)
            tex = None if win is None or prep is None else functools.partial(_textured_map, win, prep, (h, w))
            return res.measured, None if conf is None else functools.cache(conf), res.lr_consistent, tex
        left, right = pad_views(grey(left[rows]), grey(right[rows]), pad_l, pad_r)
        res, win, prep, later = pipe._run(left, right)
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
        tex = None if win is None or prep is None else (
            lambda: _at_rows(_textured_map(win, prep, left.shape[:2])[:, cols], rows, h, False))
        return measured, conf, lr, tex


def _place_confidence(full: np.ndarray, win: Window, conf: np.ndarray) -> None:
    """Write a 0..255 confidence under the region (:meth:`DisparityPipeline._confidence`) into ``full`` as 0..1."""
    full[win.outer()] = np.clip(conf * np.float32(1.0 / 255.0), 0.0, 1.0)


def _at_rows(band: np.ndarray, rows: slice, height: int, fill) -> np.ndarray:
    """``band`` (the input's ``rows``) placed in a (``height``, W) map filled with ``fill`` elsewhere."""
    out = np.empty((height, band.shape[1]), band.dtype)
    out[:rows.start] = fill
    out[rows] = band
    out[rows.stop:] = fill
    return out


def _upsample(win: Window, fn, *args, interpolation: int, margin: int = 0) -> np.ndarray:
    """``fn(*args)`` (a map over the matched crop) resized to input px under the region only.

    With a whole-number :attr:`Window.factor` k only the matched sub-block under the region
    (``margin`` matched px more each side) is resized, by k: each input pixel gets the value the
    whole crop's resize gives it (nearest: the same source pixel; linear: the same neighbours and
    weights, given a margin of 1). Otherwise the whole crop is resized and cut."""
    full = fn(*args)
    k = win.factor
    if k is None:
        return cv2.resize(full, win.crop_size, interpolation=interpolation)[win.inner()]
    x0, y0, x1, y1 = win.inner_matched(margin)
    up = cv2.resize(full[y0:y1, x0:x1], ((x1 - x0) * k, (y1 - y0) * k), interpolation=interpolation)
    ys, xs = win.inner()
    return up[ys.start - y0 * k:ys.stop - y0 * k, xs.start - x0 * k:xs.stop - x0 * k]


def _textured_map(win: Window, prep: Prepared, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: :func:`.near.textured` of a pass's prepared views, at input resolution under its region."""
    tex = np.zeros(shape, bool)
    tex[win.outer()] = _upsample(win, textured, prep.left_m, prep.right_m, interpolation=cv2.INTER_NEAREST) > 0
    return tex


def flight_pipeline(params: StereoParams) -> DisparityPipeline:
    """What flies: the measured map, its confidence, the near check and (``compute.fine_disparities``)
    the fine pass ranging may ask for; no WLS smoothing (ranging does not use it)."""
    return DisparityPipeline(params, refine=False, near=True, fine=True)


__all__ = ["DisparityPipeline", "DisparityResult", "FineMatch", "NearCheck", "check_pair", "flight_pipeline"]
