"""Confidence: the left-right consistency of each left pixel, as OpenCV's WLS filter defines it.

OpenCV's ``DisparityWLSFilter`` computes this map before (and independently of) its
smoothing (opencv_contrib ximgproc ``disparity_filters.cpp``,
``computeConfidenceMap``). Ranging uses the map and not the smoothing, so it is
computed here on its own, value for value as OpenCV does (tested against
``getConfidenceMap``), and the smoothing runs only when its output is wanted.

The definition, in matched pixels of a (h, w) window whose SGBM answers columns
``lo = max(0, min_d + num_d)`` .. ``w - max(0, -min_d)`` (the right view the mirror):

* depth-discontinuity weight of each view: ``max(0, 1 - 0.001 / rf^2 * var)``, with
  ``var`` the variance of the x16 fixed-point disparity over a (2r+1)^2 box,
  r = ceil(block_size / 2); a pixel at a depth edge (or next to an unmatched one,
  which holds OpenCV's invalid value) weighs less;
* left-right check: the left pixel x with disparity d and the right pixel x - d
  must agree within ``int(rf * 24)`` x16 units (1.5 px at rf = 1); then the
  confidence is the smaller of the two weights, else 0. A left pixel whose right
  partner lies outside the right view's answered columns is not checked and keeps
  its own weight (OpenCV's rule): the window geometry keeps such pixels out of the
  ranging region (:func:`.window.window`).

``rf`` is the matched width over the guide's width (1 unless WLS would filter at
the input resolution of a downscaled match). Outside the answered columns the
confidence is 0. The result is 0..255 float32, as OpenCV's.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from uav_depth.core.params import SGBMParams

#: OpenCV's DisparityWLSFilter defaults (init): left-right threshold in x16 disparity units, and
#: the roll-off of the depth-discontinuity weight per unit of x16 disparity variance.
LRC_THRESH_X16 = 24
ROLL_OFF = 0.001


def lr_confidence(left16: np.ndarray, right16: np.ndarray, sgbm: SGBMParams, resize_factor: float = 1.0
                  ) -> np.ndarray:
    """(h, w) float32 0..255 left-right confidence of the left matcher's ``left16`` given the right
    matcher's ``right16`` (both int16 x16, same shape)."""
    h, w = left16.shape
    lo = max(0, sgbm.min_disparity + sgbm.num_disparities)
    ro = max(0, -sgbm.min_disparity)
    width = w - lo - ro
    conf = np.zeros((h, w), np.float32)
    if width <= 0:
        return conf
    rf = np.float32(resize_factor)
    roll = np.float32(ROLL_OFF) / (rf * rf)
    k = 2 * math.ceil(0.5 * sgbm.block_size) + 1

    def weight(disp16: np.ndarray) -> np.ndarray:
        # Filtered as float32 (exact for x16 disparities): OpenCV's sqrBoxFilter of int16 input, as
        # the Python binding calls it, rounds differently from the one the WLS filter calls.
        disp = disp16.astype(np.float32)
        mean = cv2.boxFilter(disp, cv2.CV_32F, (k, k))
        var = cv2.sqrBoxFilter(disp, cv2.CV_32F, (k, k)) - mean * mean
        return np.maximum(np.float32(1.0) - roll * var, np.float32(0.0))

    left_w = np.zeros((h, w), np.float32)
    right_w = np.zeros((h, w), np.float32)
    left_w[:, lo:lo + width] = weight(left16[:, lo:lo + width])
    right_w[:, ro:ro + width] = weight(right16[:, ro:ro + width])

    cols = np.arange(lo, lo + width)
    dl = left16[:, lo:lo + width].astype(np.int32)
    ridx = cols[None, :] - (dl >> 4)
    checked = (ridx >= ro) & (ridx < ro + width)
    safe = np.where(checked, ridx, ro)
    rows = np.arange(h)[:, None]
    dr = right16[rows, safe].astype(np.int32)
    agree = np.abs(dl + dr) < int(rf * LRC_THRESH_X16)
    own = left_w[:, lo:lo + width]
    both = np.minimum(own, right_w[rows, safe])
    conf[:, lo:lo + width] = np.where(checked, np.where(agree, both, np.float32(0.0)), own)
    return conf * np.float32(255.0)
