"""Rectification: raw pairs -> rectified pairs with OpenCV, or a pass-through for rectified sources.

A raw calibration (K, D of both cameras, R and T from left to right, T in metres)
is turned into remap tables once with ``cv2.stereoRectify`` (zero disparity at
infinity, alpha 0: only valid pixels) and ``cv2.initUndistortRectifyMap``; the
rectified calibration (focal length, principal point, baseline) comes from the
new projection matrices. A rectified calibration passes frames through unchanged.
"""

from __future__ import annotations

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import CalibrationError, FrameError


class Rectifier:
    """``rectifier(left, right) -> (left, right)`` rectified; ``.calibration`` is the rectified calibration."""

    def __init__(self, calibration: Calibration):
        self.raw = calibration
        self.maps = None
        if not calibration.is_raw:
            self.calibration = calibration
            return
        import cv2

        size = (calibration.width, calibration.height)
        k1, d1 = np.asarray(calibration.k_left, float), np.asarray(calibration.d_left, float)
        k2, d2 = np.asarray(calibration.k_right, float), np.asarray(calibration.d_right, float)
        r, t = np.asarray(calibration.r, float), np.asarray(calibration.t, float).reshape(3, 1)
        if abs(t[0, 0]) < abs(t[1, 0]) or t[0, 0] == 0:
            raise CalibrationError(f"calibration.t {t.ravel().tolist()}: the cameras must sit side by side "
                                   "(|T_x| > |T_y|); vertical stereo is not supported")
        if t[0, 0] > 0:
            raise CalibrationError(f"calibration.t {t.ravel().tolist()}: the right camera must be at +x of the "
                                   "left one (T_x < 0 in OpenCV's convention); are left and right swapped?")
        r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(k1, d1, k2, d2, size, r, t, flags=cv2.CALIB_ZERO_DISPARITY,
                                                    alpha=0)
        # 16-bit fixed-point maps: remap is about twice as fast as with float maps.
        self.maps = (cv2.initUndistortRectifyMap(k1, d1, r1, p1, size, cv2.CV_16SC2),
                     cv2.initUndistortRectifyMap(k2, d2, r2, p2, size, cv2.CV_16SC2))
        focal = float(p1[0, 0])
        baseline = -float(p2[0, 3]) / float(p2[0, 0])    # P2[0,3] = -f * B (units of T: metres)
        self.calibration = Calibration(focal_px=focal, baseline_m=baseline, width=calibration.width,
                                       height=calibration.height, cx=float(p1[0, 2]), cy=float(p1[1, 2]),
                                       extra={"rectified_from": "raw K/D/R/T"})

    @property
    def passthrough(self) -> bool:
        return self.maps is None

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        want = (self.raw.height, self.raw.width)
        if left.shape[:2] != want or right.shape[:2] != want:
            raise FrameError(f"frames are {left.shape[1]}x{left.shape[0]} but the calibration is for "
                             f"{self.raw.width}x{self.raw.height}")
        if self.maps is None:
            return left, right
        import cv2

        (lx, ly), (rx, ry) = self.maps
        return (cv2.remap(left, lx, ly, cv2.INTER_LINEAR), cv2.remap(right, rx, ry, cv2.INTER_LINEAR))
