"""The disparity stage: OpenCV SGBM, a right matcher and the WLS filter.

This is the one disparity function of the project: the daemon flies it and the
tuner scores it. Build it from validated :class:`StereoParams`; ``compute`` maps a
rectified pair to an (H, W) float32 disparity in pixels of the left image, NaN
where there is no estimate.

OpenCV trap (verified on 5.0.0): ``cv2.ximgproc.createDisparityWLSFilter(matcher)``
overwrites the matcher's disp12MaxDiff (to 1000000), uniquenessRatio (0) and
speckleWindowSize (0). Unless they are set again, three of the paper's nine
parameters do nothing. We set them again, then build the right matcher from the
restored left matcher so both sides use the same parameters.

Speed levers (``compute.*``): match only ``compute.roi`` plus the disparity search
margin, at ``compute.scale`` of the input resolution, grey if ``compute.grey``,
with WLS at the input or the matched resolution (``compute.wls_at``). Whatever
they say, every output map is (H, W) at the input's resolution with disparities
in input pixels; outside the region disparities are NaN and confidence is 0. With
the defaults the pipeline computes exactly OpenCV's sample (full frame, full
resolution, colour as given).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Mapping

import cv2
import numpy as np

from uav_depth.core.errors import FrameError, ParameterWarning
from uav_depth.core.params import OPENCV_COST_MAX, StereoParams


@dataclass(frozen=True)
class DisparityResult:
    """Output of one pipeline run.

    ``disparity``: (H, W) float32 px, NaN where invalid; the WLS output when WLS is
    enabled. ``measured``: (H, W) float32 px of the left matcher alone, after its
    uniqueness, left-right and speckle checks: the pixels that were really matched,
    not filled in by WLS. ``confidence``: (H, W) float32 in 0..1 from WLS's
    left-right confidence map, or None without WLS. ``warning``: why the map is
    empty when the parameters cannot be computed. ``timings_ms``: wall time of
    each stage of this run (prepare, match_left, match_right, wls, assemble), ms.
    """

    disparity: np.ndarray
    measured: np.ndarray
    confidence: np.ndarray | None
    warning: str | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)


class _Laps:
    """Stage stopwatch: ``lap(name)`` books the time since the previous lap under ``name``."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = self.ms.get(name, 0.0) + (now - self._t) * 1000.0
        self._t = now


def _to_float(disp16: np.ndarray, min_disparity: int, scale: float = 1.0) -> np.ndarray:
    """OpenCV fixed-point disparity (x16) to float px with NaN for invalid.

    ``scale`` multiplies the result: matched-image pixels to input pixels.
    """
    out = disp16.astype(np.float32) * np.float32(scale / 16.0)
    out[disp16 < min_disparity * 16] = np.nan
    return out


#: Rows and columns of real image matched around the region (in matched pixels, at
#: least this many and half a block more), so that blocks at the region's edge see
#: image, not OpenCV's replicated border, and the top-down pass has some run-in.
_CONTEXT_PX = 4


@dataclass(frozen=True)
class _Window:
    """Where a region is matched: the crop of the input and the region inside it (input px)."""

    crop: tuple[int, int, int, int]       # x0, y0, x1, y1 of the crop in the input image
    region: tuple[int, int, int, int]     # x0, y0, x1, y1 of the answered region in the input image
    matched: tuple[int, int]              # (width, height) the crop is matched at


def _window(params: StereoParams, width: int, height: int) -> _Window:
    """The crop that holds ``compute.roi`` plus the disparity search margin, and its matched size.

    A left pixel at x matches right pixels x - d for d in min_disparity ..
    min_disparity + num_disparities - 1 (matched pixels), so the crop reaches that
    far left of the region (and right of it for a negative min_disparity).
    """
    sg, cp = params.sgbm, params.compute
    rx0, ry0, rx1, ry1 = cp.roi_pixels(width, height)
    context = max(_CONTEXT_PX, sg.block_size // 2 + 1)
    left = math.ceil((max(0, sg.min_disparity + sg.num_disparities) + context) / cp.scale)
    right = math.ceil((max(0, -sg.min_disparity) + context) / cp.scale)
    vert = math.ceil(context / cp.scale)
    crop = (max(0, rx0 - left), max(0, ry0 - vert), min(width, rx1 + right), min(height, ry1 + vert))
    cw, ch = crop[2] - crop[0], crop[3] - crop[1]
    matched = (max(1, round(cw * cp.scale)), max(1, round(ch * cp.scale)))
    return _Window(crop, (rx0, ry0, rx1, ry1), matched)


def check_pair(left: np.ndarray, right: np.ndarray) -> None:
    """Raise FrameError unless ``left``/``right`` form a usable pair."""
    for name, img in (("left", left), ("right", right)):
        if not isinstance(img, np.ndarray) or img.size == 0:
            raise FrameError(f"{name} image is empty or not an array")
        if img.dtype != np.uint8:
            raise FrameError(f"{name} image must be uint8, but got {img.dtype}")
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
            raise FrameError(f"{name} image must be (H, W) grey or (H, W, 3) colour, but got shape {img.shape}")
    if left.shape != right.shape:
        raise FrameError(f"left and right images must have the same shape, but got {left.shape} and {right.shape}")


class DisparityPipeline:
    """SGBM (+ right matcher + WLS) built once from validated parameters.

    Not thread-safe (OpenCV matcher objects keep state): build one per thread or
    process. Building is cheap (well under a millisecond).
    """

    def __init__(self, params: StereoParams):
        self.params = params
        sg = params.sgbm
        self.left_matcher = cv2.StereoSGBM_create(
            minDisparity=sg.min_disparity, numDisparities=sg.num_disparities, blockSize=sg.block_size,
            P1=sg.p1, P2=sg.p2, disp12MaxDiff=sg.disp12_max_diff, preFilterCap=sg.pre_filter_cap,
            uniquenessRatio=sg.uniqueness_ratio, speckleWindowSize=sg.speckle_window_size,
            speckleRange=sg.speckle_range, mode=sg.mode_flag)
        self.right_matcher = None
        self.wls = None
        if params.wls.enabled:
            self.wls = cv2.ximgproc.createDisparityWLSFilter(self.left_matcher)
            # createDisparityWLSFilter just clobbered these three; give them back.
            self.left_matcher.setDisp12MaxDiff(sg.disp12_max_diff)
            self.left_matcher.setUniquenessRatio(sg.uniqueness_ratio)
            self.left_matcher.setSpeckleWindowSize(sg.speckle_window_size)
            self.wls.setLambda(params.wls.lambda_)
            self.wls.setSigmaColor(params.wls.sigma_color)
            self.right_matcher = cv2.ximgproc.createRightMatcher(self.left_matcher)
        self._overflow = None
        if sg.overflows:
            self._overflow = (f"sgbm.p1={sg.p1}/sgbm.p2={sg.p2} exceed OpenCV's 16-bit cost limit "
                              f"{OPENCV_COST_MAX}: no disparity computed")

    def run(self, left: np.ndarray, right: np.ndarray) -> DisparityResult:
        """Disparity of a rectified pair (uint8 grey or BGR colour, same shape).

        Every map is (H, W) at the input's resolution whatever ``compute.*`` says;
        outside ``compute.roi`` disparities are NaN and confidence is 0.
        """
        laps = _Laps()
        check_pair(left, right)
        h, w = left.shape[:2]
        if self._overflow is not None:
            warnings.warn(self._overflow, ParameterWarning, stacklevel=2)
            empty = np.full((h, w), np.nan, np.float32)
            return DisparityResult(empty, empty.copy(), None, self._overflow)
        if not self.params.compute.is_baseline:
            return self._run_window(left, right, laps)
        laps.lap("prepare")
        min_d = self.params.sgbm.min_disparity
        left16 = self.left_matcher.compute(left, right)
        laps.lap("match_left")
        measured = _to_float(left16, min_d)
        if self.wls is None:
            laps.lap("assemble")
            return DisparityResult(measured, measured, None, timings_ms=laps.ms)
        right16 = self.right_matcher.compute(right, left)
        laps.lap("match_right")
        filtered16 = self.wls.filter(left16, left, disparity_map_right=right16)
        conf = self.wls.getConfidenceMap()
        laps.lap("wls")
        conf = np.clip(conf * np.float32(1.0 / 255.0), 0.0, 1.0).astype(np.float32, copy=False)
        disparity = _to_float(filtered16, min_d)
        laps.lap("assemble")
        return DisparityResult(disparity, measured, conf, timings_ms=laps.ms)

    def _run_window(self, left: np.ndarray, right: np.ndarray, laps: _Laps) -> DisparityResult:
        """Match ``compute.roi`` (plus margin) at ``compute.scale``, grey if asked; paste into full-size maps."""
        h, w = left.shape[:2]
        sg, cp = self.params.sgbm, self.params.compute
        win = _window(self.params, w, h)
        cx0, cy0, cx1, cy1 = win.crop
        lc, rc = left[cy0:cy1, cx0:cx1], right[cy0:cy1, cx0:cx1]
        if cp.grey and lc.ndim == 3:
            if lc.shape[2] == 3:
                lc, rc = cv2.cvtColor(lc, cv2.COLOR_BGR2GRAY), cv2.cvtColor(rc, cv2.COLOR_BGR2GRAY)
            else:
                lc, rc = lc[..., 0], rc[..., 0]
        crop_size = (cx1 - cx0, cy1 - cy0)
        if win.matched != crop_size:
            # INTER_AREA averages the pixels it drops: no aliasing of fine bark texture.
            lm = cv2.resize(lc, win.matched, interpolation=cv2.INTER_AREA)
            rm = cv2.resize(rc, win.matched, interpolation=cv2.INTER_AREA)
        else:
            lm, rm = lc, rc
        ratio = crop_size[0] / win.matched[0]          # matched px -> input px, along the baseline
        disparity = np.full((h, w), np.nan, np.float32)
        measured = np.full((h, w), np.nan, np.float32)
        confidence = None if self.wls is None else np.zeros((h, w), np.float32)
        span = max(0, sg.min_disparity + sg.num_disparities) + max(0, -sg.min_disparity)
        laps.lap("prepare")
        if win.matched[0] <= span:          # narrower than the search: nothing can be matched
            return DisparityResult(disparity, measured, confidence, timings_ms=laps.ms)

        left16 = self.left_matcher.compute(lm, rm)
        laps.lap("match_left")
        meas = _to_float(left16, sg.min_disparity, ratio)
        if win.matched != crop_size:
            # Nearest, not linear: a measured value is one pixel's match, never a blend with NaN.
            meas = cv2.resize(meas, crop_size, interpolation=cv2.INTER_NEAREST)
        rx0, ry0, rx1, ry1 = win.region
        inner = (slice(ry0 - cy0, ry1 - cy0), slice(rx0 - cx0, rx1 - cx0))
        outer = (slice(ry0, ry1), slice(rx0, rx1))
        measured[outer] = meas[inner]
        if self.wls is None:
            disparity[outer] = meas[inner]
            laps.lap("assemble")
            return DisparityResult(disparity, measured, None, timings_ms=laps.ms)
        laps.lap("assemble")
        right16 = self.right_matcher.compute(rm, lm)
        laps.lap("match_right")
        if cp.wls_at == "matched" and win.matched != crop_size:
            # WLS at the matched resolution (a quarter of the pixels at scale 0.5), then
            # resized: linear for the smooth filtered map (a NaN neighbour stays NaN).
            filtered16 = self.wls.filter(left16, lm, disparity_map_right=right16)
            conf = self.wls.getConfidenceMap()
            laps.lap("wls")
            filt = cv2.resize(_to_float(filtered16, sg.min_disparity, ratio), crop_size,
                              interpolation=cv2.INTER_LINEAR)
            conf = cv2.resize(conf, crop_size, interpolation=cv2.INTER_LINEAR)
        else:
            # Given the full-resolution guide, OpenCV's WLS upsamples the low-resolution
            # disparity itself (scaling values by the width ratio) and filters at full
            # resolution, so edges follow the real image.
            filtered16 = self.wls.filter(left16, lc, disparity_map_right=right16)
            conf = self.wls.getConfidenceMap()
            laps.lap("wls")
            filt = filtered16.astype(np.float32) * np.float32(1.0 / 16.0)
            # Below the smallest searched disparity (in input px) is invalid. OpenCV fills
            # what lies outside its valid band with 16*(min_disparity-1), unscaled: with a
            # negative min_disparity and upscaling that is not below the threshold.
            filt[(filtered16 < sg.min_disparity * 16 * ratio)
                 | (filtered16 == 16 * (sg.min_disparity - 1))] = np.nan
        disparity[outer] = filt[inner]
        confidence[outer] = np.clip(conf[inner] * np.float32(1.0 / 255.0), 0.0, 1.0)  # type: ignore[index]
        laps.lap("assemble")
        return DisparityResult(disparity, measured, confidence, timings_ms=laps.ms)

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(H, W) float32 disparity in px of the left image, NaN where invalid."""
        return self.run(left, right).disparity
