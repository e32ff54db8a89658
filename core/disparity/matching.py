"""The match stage: left SGBM over the window, the right SGBM and the left-right confidence, and (in the
paper's pipeline) OpenCV's WLS smoothing; the maps put back at the input's size.

:class:`MatchStage` is built once from validated parameters and runs one pair; the
declared pipelines (:mod:`.pipeline`) and the near pass (:mod:`.near`) each own one.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from uav_depth.core.disparity.confidence import confidence_maps
from uav_depth.core.disparity.match import Matchers, build_matchers, match_left, match_right, to_float
from uav_depth.core.disparity.prepare import Prepared, check_pair, prepare
from uav_depth.core.disparity.result import DisparityResult, Laps
from uav_depth.core.disparity.window import Window, search_span, window
from uav_depth.core.errors import ParameterWarning
from uav_depth.core.params import OPENCV_COST_MAX, StereoParams


@dataclass(frozen=True)
class Matched:
    """One run of the match stage: the result, and what the near pass reads beside it. ``window`` and
    ``prepared``: None when nothing was matched; ``later_confidence``: with ``lazy_confidence``, computes the
    confidence map the result leaves None (else None)."""

    result: DisparityResult
    window: Window | None = None
    prepared: Prepared | None = None
    later_confidence: Callable[[], np.ndarray] | None = None


class MatchStage:
    """The matchers built once from validated parameters (not thread-safe: OpenCV matcher objects keep state).

    ``smooth``: run WLS's smoothing for ``DisparityResult.disparity`` (when ``wls.enabled``); without it
    ``disparity`` holds the measured values and the run skips the smoothing's cost. ``measured`` and
    ``confidence`` do not depend on it (but for the left match's columns, :meth:`_match_left`).
    ``lazy_confidence`` (the near pass's): compute the left-right check and leave the confidence's depth-edge
    weights, most of its cost, to :attr:`Matched.later_confidence`.
    """

    def __init__(self, params: StereoParams, smooth: bool, lazy_confidence: bool = False):
        self.params = params
        self.smooth = smooth and params.wls.enabled
        self._lazy_confidence = lazy_confidence
        self.matchers: Matchers = build_matchers(params)
        sg = params.sgbm
        self._overflow = None
        if sg.overflows:
            self._overflow = (f"sgbm.p1={sg.p1}/sgbm.p2={sg.p2} exceed OpenCV's 16-bit cost limit "
                              f"{OPENCV_COST_MAX}: no disparity computed")

    def run(self, left: np.ndarray, right: np.ndarray) -> Matched:
        """One pass of the stages over a rectified pair (uint8 grey or BGR colour, same shape)."""
        laps = Laps()
        check_pair(left, right)
        h, w = left.shape[:2]
        if self._overflow is not None:
            warnings.warn(self._overflow, ParameterWarning, stacklevel=3)
            empty = np.full((h, w), np.nan, np.float32)
            return Matched(DisparityResult(empty, empty.copy(), None, self._overflow))
        win = window(self.params, w, h)
        # With lazy_confidence the map is made when asked for (:meth:`_confidence_map`), not here.
        conf_full = None if self.matchers.right is None or self._lazy_confidence else np.zeros((h, w), np.float32)
        measured = np.full((h, w), np.nan, np.float32)
        if win.matched[0] <= search_span(self.params):    # narrower than the search: nothing can be matched
            laps.lap("prepare")
            return Matched(DisparityResult(np.full((h, w), np.nan, np.float32), measured, conf_full,
                                           timings_ms=laps.ms))
        prep = prepare(self.params.compute, win, left, right)
        laps.lap("prepare")
        left16 = self._match_left(win, prep)
        laps.lap("match_left")
        measured[win.outer()] = self._measured(win, left16)
        if self.matchers.right is None:
            laps.lap("assemble")
            return Matched(DisparityResult(measured, measured, None, timings_ms=laps.ms), win, prep)
        right16 = match_right(self.matchers, prep.left_m, prep.right_m)
        laps.lap("match_right")
        conf, lr = self._confidence(win, left16, right16, weights=not self._lazy_confidence)
        later = None
        if conf is None:
            later = functools.partial(self._confidence_map, win, left16, right16, (h, w))
        else:
            place_confidence(conf_full, win, conf)
        lr_full = np.zeros((h, w), bool)
        lr_full[win.outer()] = lr > 0
        laps.lap("confidence")
        if not self.smooth:
            laps.lap("assemble")
            return Matched(DisparityResult(measured, measured, conf_full, timings_ms=laps.ms, lr_consistent=lr_full),
                           win, prep, later)
        filt = self._wls(win, prep, left16, right16)
        laps.lap("wls")
        disparity = np.full((h, w), np.nan, np.float32)
        disparity[win.outer()] = filt[win.inner()]
        laps.lap("assemble")
        return Matched(DisparityResult(disparity, measured, conf_full, timings_ms=laps.ms, lr_consistent=lr_full),
                       win, prep, later)

    def _match_left(self, win: Window, prep: Prepared) -> np.ndarray:
        """The left matcher over the columns it needs (:attr:`Window.left_width`), at the crop's matched
        width: the columns right of them hold OpenCV's invalid value. With the WLS smoothing on
        (``smooth``), over the whole crop: the smoothing spreads what it is given into the
        region, so those columns' real matches keep its map unchanged (the tuner's faithful mode). The
        region's measured pixels differ between the two by SGBM's right-to-left path alone (under 1 % by
        more than 1 px, tested)."""
        lw = win.left_width
        if self.smooth or lw >= win.matched[0] or lw <= search_span(self.params):
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
        return upsample(win, to_float, left16, min_d, win.ratio, interpolation=cv2.INTER_NEAREST)

    def _wls_at_matched(self, win: Window) -> bool:
        return self.params.compute.wls_at == "matched" or not win.resized

    def _confidence_map(self, win: Window, left16: np.ndarray, right16: np.ndarray,
                        shape: tuple[int, int]) -> np.ndarray:
        """The (H, W) 0..1 confidence map of a run (``lazy_confidence``: computed when asked for)."""
        full = np.zeros(shape, np.float32)
        place_confidence(full, win, self._confidence(win, left16, right16)[0])
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
        return (None if conf is None else upsample(win, lambda: conf, interpolation=cv2.INTER_LINEAR, margin=1),
                upsample(win, lambda: lr, interpolation=cv2.INTER_NEAREST, margin=1))

    def _wls(self, win: Window, prep: Prepared, left16: np.ndarray, right16: np.ndarray) -> np.ndarray:
        """WLS-smoothed disparity over the crop, input px, NaN where invalid."""
        min_d = self.params.sgbm.min_disparity
        assert self.matchers.wls is not None
        if win.resized and self.params.compute.wls_at == "matched":
            # WLS at the matched resolution (a quarter of the pixels at scale 0.5), then
            # resized: linear for the smooth filtered map (a NaN neighbour stays NaN).
            filtered16 = self.matchers.wls.filter(left16, prep.left_m, disparity_map_right=right16)
            return cv2.resize(to_float(filtered16, min_d, win.ratio), win.crop_size, interpolation=cv2.INTER_LINEAR)
        # Given the full-resolution guide, OpenCV's WLS upsamples the low-resolution
        # disparity itself (scaling values by the width ratio) and filters at full
        # resolution, so edges follow the real image.
        filtered16 = self.matchers.wls.filter(left16, prep.left, disparity_map_right=right16)
        filt = filtered16.astype(np.float32) * np.float32(1.0 / 16.0)
        # Below the smallest searched disparity (in input px) is invalid. OpenCV fills
        # what lies outside its valid band with 16*(min_disparity-1), unscaled: with a
        # negative min_disparity and upscaling that is not below the threshold.
        filt[(filtered16 < min_d * 16 * win.ratio) | (filtered16 == 16 * (min_d - 1))] = np.nan
        return filt


def place_confidence(full: np.ndarray, win: Window, conf: np.ndarray) -> None:
    """Write a 0..255 confidence under the region (:meth:`MatchStage._confidence`) into ``full`` as 0..1."""
    full[win.outer()] = np.clip(conf * np.float32(1.0 / 255.0), 0.0, 1.0)


def upsample(win: Window, fn, *args, interpolation: int, margin: int = 0) -> np.ndarray:
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
