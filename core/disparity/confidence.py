"""Confidence: the left-right consistency of each left pixel, as OpenCV's WLS filter defines it.

OpenCV's ``DisparityWLSFilter`` computes this map before (and independently of) its
smoothing (opencv_contrib ximgproc ``disparity_filters.cpp``,
``computeConfidenceMap``). Ranging uses the map and not the smoothing, so it is
computed here on its own, as OpenCV does (tested against
``getConfidenceMap`` where the two definitions meet, see below), and the smoothing
runs only when its output is wanted.

The definition, in matched pixels of a (h, w) window whose SGBM answers columns
``lo = max(0, min_d + num_d)`` .. ``w - max(0, -min_d)`` (the right view the mirror):

* depth-discontinuity weight of each view: ``max(0, 1 - 0.001 / rf^2 * var)``, with
  ``var`` the variance of the x16 fixed-point disparity over a (2r+1)^2 box,
  r = ceil(block_size / 2); a pixel at a depth edge weighs less. **One change from
  OpenCV**: the variance is taken over the box's *matched* pixels only, and a pixel
  with fewer than 90 % of its box matched weighs 0. OpenCV counts an unmatched
  neighbour's invalid value ((min_d - 1) x 16) as a disparity, so every pixel within
  r of a hole weighs 0: a thin branch with a few unmatched pixels lost all its
  confidence and ranging read the trunk behind it (the manual baseline on a 1.8 cm
  branch at 1-1.5 m: +13-19 %, docs/ranging.md). Where the box holds no hole the
  two are the same, value for value (tested against ``getConfidenceMap``);
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
#: A pixel with fewer matched neighbours than this share of its box weighs 0, as OpenCV's would: a few holes
#: (up to 4 of a 7 x 7 box, 2 of 5 x 5, none of 3 x 3) are weighed around, more are a ragged region. 0.5
#: measured too: the manual baseline's map got denser and the tuner's relative gain on real pairs smaller
#: (docs/ranging.md, *Confidence next to unmatched pixels*).
MIN_MATCHED_SHARE = 0.9


def lr_confidence(left16: np.ndarray, right16: np.ndarray, sgbm: SGBMParams, resize_factor: float = 1.0,
                  cols: tuple[int, int] | None = None) -> np.ndarray:
    """(h, w) float32 0..255 left-right confidence of the left matcher's ``left16`` given the right
    matcher's ``right16`` (both int16 x16, same shape).

    ``cols``: (c0, c1), compute only left columns c0..c1-1 (the rest is 0); each value is the
    one the whole map would hold (the filters see the same neighbours)."""
    return confidence_maps(left16, right16, sgbm, resize_factor, cols)[0]


def confidence_maps(left16: np.ndarray, right16: np.ndarray, sgbm: SGBMParams, resize_factor: float = 1.0,
                    cols: tuple[int, int] | None = None, weights: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """:func:`lr_confidence`, and the left-right check alone: a (h, w) uint8 map, 1 where the left
    pixel is matched and its right partner agrees (or lies outside the right view's answered
    columns, unchecked as in the confidence), whatever its depth-edge weight. A thin twig is all
    depth edge: its confidence is near 0 though its matches agree (ranging's thin guard uses this).

    ``weights=False``: the check alone, (None, check); the depth-edge weights (the box filters, most of
    the cost) are not computed. The check is the same map either way."""
    h, w = left16.shape
    lo = max(0, sgbm.min_disparity + sgbm.num_disparities)
    ro = max(0, -sgbm.min_disparity)
    conf = np.zeros((h, w), np.float32) if weights else None
    lr_ok = np.zeros((h, w), np.uint8)
    rf = np.float32(resize_factor)
    roll = np.float32(ROLL_OFF) / (rf * rf)
    k = 2 * math.ceil(0.5 * sgbm.block_size) + 1
    r = k // 2
    # Left columns computed, c0..c1, and the right view's answered columns ro..re.
    re = w - lo
    c0, c1 = (lo, w - ro) if cols is None else (max(lo, cols[0]), min(w - ro, cols[1]))
    if c1 <= c0 or re <= ro:
        return conf, lr_ok

    def weight(disp16: np.ndarray, invalid16: int, valid: np.ndarray) -> np.ndarray:
        # Filtered as float32 (exact for x16 disparities): OpenCV's sqrBoxFilter of int16 input, as
        # the Python binding calls it, rounds differently from the one the WLS filter calls.
        disp = disp16.astype(np.float32)
        mean = cv2.boxFilter(disp, cv2.CV_32F, (k, k))
        sq = cv2.sqrBoxFilter(disp, cv2.CV_32F, (k, k))
        var = sq - mean * mean
        invalid = (~valid).view(np.uint8)
        if invalid.any():
            # Over the matched neighbours only (module docstring): the box's sums less its holes, each of
            # which holds OpenCV's one invalid value. OpenCV's arithmetic: a third of numpy's time here.
            holes = cv2.boxFilter(invalid, cv2.CV_32F, (k, k), normalize=False)      # exact counts
            area, c = float(k * k), float(invalid16)
            n = cv2.subtract(area, holes)
            inv_n = cv2.divide(1.0, cv2.max(n, 1.0))
            mv = cv2.multiply(cv2.scaleAdd(holes, -c, cv2.multiply(mean, area)), inv_n)
            vv = cv2.subtract(cv2.multiply(cv2.scaleAdd(holes, -c * c, cv2.multiply(sq, area)), inv_n),
                              cv2.multiply(mv, mv))
            vv[cv2.bitwise_or(cv2.compare(n, MIN_MATCHED_SHARE * area, cv2.CMP_LT), invalid) > 0] = np.inf
            cv2.copyTo(vv, cv2.compare(holes, 0.0, cv2.CMP_GT), var)
        return np.maximum(np.float32(1.0) - roll * var, np.float32(0.0))

    def weight_over(disp16: np.ndarray, invalid16: int, valid: np.ndarray, a: int, b: int, lim_a: int,
                    lim_b: int) -> np.ndarray:
        """The weight of columns a..b of a view whose answered columns are lim_a..lim_b: filtered over
        r more columns each side (inside those), so the border the filter sees is the whole map's."""
        fa, fb = max(lim_a, a - r), min(lim_b, b + r)
        return weight(disp16[:, fa:fb], invalid16, valid[:, fa:fb])[:, a - fa:b - fa]

    dl = left16[:, c0:c1].astype(np.int32)
    ridx = np.arange(c0, c1)[None, :] - (dl >> 4)
    checked = (ridx >= ro) & (ridx < re)
    # The right columns these left pixels can point at (within the answered ones).
    ra = max(ro, min(c0 - max(sgbm.min_disparity + sgbm.num_disparities - 1, 0), re - 1))
    rb = min(re, max(c1 + 1 - sgbm.min_disparity, ra + 1))    # +1: an unmatched pixel points one right
    safe = np.clip(np.where(checked, ridx, ra), ra, rb - 1)
    # Each left pixel's partner by one flat index into the (contiguous) map: half the time of a two-array index.
    dr = np.ascontiguousarray(right16).ravel().take(safe + np.arange(0, h * w, w)[:, None]).astype(np.int32)
    agree = np.abs(dl + dr) < int(rf * LRC_THRESH_X16)
    lr_ok[:, c0:c1] = (dl >= sgbm.min_disparity * 16) & (agree | ~checked)
    if conf is None:
        return None, lr_ok
    # OpenCV marks an unmatched pixel with a value below the searched range ((min_d - 1) x 16, and the
    # right matcher's mirror of it); a matched right pixel holds minus its disparity.
    own = weight_over(left16, (sgbm.min_disparity - 1) * 16, left16 >= sgbm.min_disparity * 16, c0, c1, lo, w - ro)
    right_min = 1 - (sgbm.min_disparity + sgbm.num_disparities)      # the right matcher's own min_disparity
    right_w = weight_over(right16, (right_min - 1) * 16, (right16 <= -sgbm.min_disparity * 16)
                          & (right16 >= right_min * 16), ra, rb, ro, re)
    both = np.minimum(own, right_w[np.arange(h)[:, None], safe - ra])
    conf[:, c0:c1] = np.where(checked, np.where(agree, both, np.float32(0.0)), own)
    return conf * np.float32(255.0), lr_ok
