"""What a log's camera does to its images, measured from its frames, so the safety sweep is rendered alike.

The sweep's scenes carry the imaging of the scenes the shipped files were measured on. A cheaper camera's
frames are noisier, and a candidate tuned on them must be judged on frames like them: on the noisy 640x480 rig
of bench/new_rig.py, a file tuned on its frames passed a sweep rendered with the scenes' own noise and then
read leafy frames of that camera up to 26 % farther than the branch (docs/measurements/tuning-new-rig.md).

- Sensor noise: Immerkaer's estimate (J. Immerkaer, *Fast noise variance estimation*, CVIU 64(2), 1996): the
  mean absolute response to the difference of two Laplacians, x sqrt(pi / 2) / 6, over the left image.
  Texture adds to it a little, saturated pixels (sky) take from it; the median over the frames is used.
- The right eye's gain and black level against the left: the ratio of the two images' spreads and the
  difference of their means (the same scene seen twice), median over the frames.

Blur is not estimated: the sweep keeps its scenes' own.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from uav_depth.tuning.frames import FrameData

#: Immerkaer's kernel: the difference of two discrete Laplacians, blind to planes and linear ramps.
_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


@dataclass(frozen=True)
class Imaging:
    """A log's imaging: sensor noise (grey levels, 1 sigma) and the right eye's gain and offset against the left."""

    noise_std: float
    right_gain: float
    right_offset: float


def _grey(image: np.ndarray) -> np.ndarray:
    return (image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)).astype(np.float32)


def noise_std(image: np.ndarray) -> float:
    """Immerkaer's estimate of the sensor noise of one (H, W) or (H, W, 3) uint8 image, grey levels."""
    response = cv2.filter2D(_grey(image), -1, _KERNEL)[1:-1, 1:-1]
    return float(math.sqrt(math.pi / 2.0) * np.abs(response).mean() / 6.0)


def estimate(frames: Sequence[FrameData]) -> Imaging | None:
    """The imaging of ``frames`` (medians over them), None without a frame."""
    if not frames:
        return None
    noise, gain, offset = [], [], []
    for f in frames:
        left, right = _grey(f.left), _grey(f.right)
        noise.append(noise_std(f.left))
        g = float(right.std() / max(left.std(), 1e-6))
        gain.append(g)
        offset.append(float(right.mean() - g * left.mean()))
    return Imaging(statistics.median(noise), statistics.median(gain), statistics.median(offset))
