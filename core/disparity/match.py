"""Match: the left SGBM matcher and, for the left-right check, the right one.

OpenCV trap (verified on 5.0.0): ``cv2.ximgproc.createDisparityWLSFilter(matcher)``
overwrites the matcher's disp12MaxDiff (to 1000000), uniquenessRatio (0) and
speckleWindowSize (0). Unless they are set again, three of the paper's nine
parameters do nothing. We set them again, then build the right matcher from the
restored left matcher so both sides use the same parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from uav_depth.core.params import StereoParams


@dataclass(frozen=True)
class Matchers:
    """OpenCV objects built once from validated parameters (not thread-safe: they keep state).

    ``right`` and ``wls`` are None when ``wls.enabled`` is false.
    """

    left: Any
    right: Any | None
    wls: Any | None


def build_matchers(params: StereoParams) -> Matchers:
    sg = params.sgbm
    left = cv2.StereoSGBM_create(
        minDisparity=sg.min_disparity, numDisparities=sg.num_disparities, blockSize=sg.block_size,
        P1=sg.p1, P2=sg.p2, disp12MaxDiff=sg.disp12_max_diff, preFilterCap=sg.pre_filter_cap,
        uniquenessRatio=sg.uniqueness_ratio, speckleWindowSize=sg.speckle_window_size,
        speckleRange=sg.speckle_range, mode=sg.mode_flag)
    if not params.wls.enabled:
        return Matchers(left, None, None)
    wls = cv2.ximgproc.createDisparityWLSFilter(left)
    # createDisparityWLSFilter just clobbered these three; give them back.
    left.setDisp12MaxDiff(sg.disp12_max_diff)
    left.setUniquenessRatio(sg.uniqueness_ratio)
    left.setSpeckleWindowSize(sg.speckle_window_size)
    wls.setLambda(params.wls.lambda_)
    wls.setSigmaColor(params.wls.sigma_color)
    return Matchers(left, cv2.ximgproc.createRightMatcher(left), wls)


def match_left(m: Matchers, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(h, w) int16 disparity x16 of the left image (OpenCV's fixed point)."""
    return m.left.compute(left, right)


def match_right(m: Matchers, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(h, w) int16 disparity x16 of the right image, negative (OpenCV's right matcher)."""
    assert m.right is not None
    return m.right.compute(right, left)


def to_float(disp16: np.ndarray, min_disparity: int, scale: float = 1.0) -> np.ndarray:
    """OpenCV fixed-point disparity (x16) to float px with NaN for invalid.

    ``scale`` multiplies the result: matched-image pixels to input pixels.
    """
    out = disp16.astype(np.float32) * np.float32(scale / 16.0)
    out[disp16 < min_disparity * 16] = np.nan
    return out
