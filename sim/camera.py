"""From rendered radiance to the 8-bit images a real stereo rig gives, with its differences between the eyes.

Per view: contrast and brightness, optical blur, Gaussian sensor noise, and for the
right eye alone an exposure/gain ratio (``right_gain``, applied to signal and
noise, as an analogue gain does), a black-level offset (``right_offset``) and extra
blur (``right_blur_sigma``: the eyes are not focused alike). The rectification
error (``rect_error_px``) is geometric and applied by the renderer's rays.
"""

from __future__ import annotations

import math
from typing import Protocol

import cv2
import numpy as np

#: BGR tint per label (background, trunk, branch, twig, needle, sky).
TINT = np.array([[0.85, 1.0, 0.9], [0.55, 0.75, 1.0], [0.6, 0.8, 1.05], [0.6, 0.8, 1.05], [0.55, 0.95, 0.7],
                 [1.05, 1.0, 0.95]], np.float32)


class _Config(Protocol):
    contrast: float
    brightness: float
    blur_sigma: float
    noise_std: float
    color: bool
    right_gain: float
    right_offset: float
    right_blur_sigma: float


def finish(c: _Config, intensity: np.ndarray, labels: np.ndarray, rng: np.random.Generator,
           right: bool = False) -> np.ndarray:
    """(H, W) uint8 grey, or (H, W, 3) BGR with ``c.color``, from (H, W) float32 radiance (0..1-ish)."""
    img = (intensity - 0.5) * c.contrast + 0.5
    img = img * 255.0 + c.brightness
    sigma = math.hypot(c.blur_sigma, c.right_blur_sigma) if right else c.blur_sigma
    if sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    if c.noise_std > 0:
        img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(c.noise_std)
    if right and (c.right_gain != 1.0 or c.right_offset != 0.0):
        img = img * np.float32(c.right_gain) + np.float32(c.right_offset)
    grey = np.clip(img, 0, 255).astype(np.uint8)
    if not c.color:
        return grey
    return np.clip(grey[..., None] * TINT[labels], 0, 255).astype(np.uint8)
