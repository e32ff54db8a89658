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
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from .errors import FrameError, ParameterWarning
from .params import OPENCV_COST_MAX, StereoParams


@dataclass(frozen=True)
class DisparityResult:
    """Output of one pipeline run.

    ``disparity``: (H, W) float32 px, NaN where invalid; the WLS output when WLS is
    enabled. ``measured``: (H, W) float32 px of the left matcher alone, after its
    uniqueness, left-right and speckle checks: the pixels that were really matched,
    not filled in by WLS. ``confidence``: (H, W) float32 in 0..1 from WLS's
    left-right confidence map, or None without WLS. ``warning``: why the map is
    empty when the parameters cannot be computed.
    """

    disparity: np.ndarray
    measured: np.ndarray
    confidence: np.ndarray | None
    warning: str | None = None


def _to_float(disp16: np.ndarray, min_disparity: int) -> np.ndarray:
    """OpenCV fixed-point disparity (x16) to float px with NaN for invalid."""
    out = disp16.astype(np.float32) * np.float32(1.0 / 16.0)
    out[disp16 < min_disparity * 16] = np.nan
    return out


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
        """Disparity of a rectified pair (uint8 grey or BGR colour, same shape)."""
        check_pair(left, right)
        h, w = left.shape[:2]
        if self._overflow is not None:
            warnings.warn(self._overflow, ParameterWarning, stacklevel=2)
            empty = np.full((h, w), np.nan, np.float32)
            return DisparityResult(empty, empty.copy(), None, self._overflow)
        min_d = self.params.sgbm.min_disparity
        left16 = self.left_matcher.compute(left, right)
        measured = _to_float(left16, min_d)
        if self.wls is None:
            return DisparityResult(measured, measured, None)
        right16 = self.right_matcher.compute(right, left)
        filtered16 = self.wls.filter(left16, left, disparity_map_right=right16)
        conf = self.wls.getConfidenceMap()
        conf = np.clip(conf * np.float32(1.0 / 255.0), 0.0, 1.0).astype(np.float32, copy=False)
        return DisparityResult(_to_float(filtered16, min_d), measured, conf)

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(H, W) float32 disparity in px of the left image, NaN where invalid."""
        return self.run(left, right).disparity
