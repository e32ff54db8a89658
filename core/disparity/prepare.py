"""Prepare: check the pair, crop the window, convert to grey if asked, resize to the matched size."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from uav_depth.core.disparity.window import Window
from uav_depth.core.errors import FrameError
from uav_depth.core.params import ComputeParams


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


def grey(img: np.ndarray) -> np.ndarray:
    """``img`` as one channel: BGR converted (OpenCV's weights), a single channel taken as it is."""
    if img.ndim == 2:
        return img
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.shape[2] == 3 else img[..., 0]


@dataclass(frozen=True)
class Prepared:
    """The window's images: ``left``/``right`` cropped (grey if asked) at input resolution (WLS's
    guide), ``left_m``/``right_m`` the same at the matched size (what SGBM sees)."""

    left: np.ndarray
    right: np.ndarray
    left_m: np.ndarray
    right_m: np.ndarray


def prepare(compute: ComputeParams, win: Window, left: np.ndarray, right: np.ndarray) -> Prepared:
    """Crop ``win.crop`` out of a checked pair, grey if ``compute.grey``, resized to ``win.matched``."""
    cx0, cy0, cx1, cy1 = win.crop
    lc, rc = left[cy0:cy1, cx0:cx1], right[cy0:cy1, cx0:cx1]
    if compute.grey:
        lc, rc = grey(lc), grey(rc)
    if win.resized:
        # INTER_AREA averages the pixels it drops: no aliasing of fine bark texture.
        lm = cv2.resize(lc, win.matched, interpolation=cv2.INTER_AREA)
        rm = cv2.resize(rc, win.matched, interpolation=cv2.INTER_AREA)
    else:
        lm, rm = lc, rc
    return Prepared(lc, rc, lm, rm)
