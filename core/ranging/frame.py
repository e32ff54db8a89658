"""One frame on its way through the ranging stages: what the stages before have found, each field written by
one stage (named beside it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging.measurement import Measurement
from uav_depth.core.ranging.nearest import NearestObject


@dataclass
class RangingFrame:
    """``disp``/``conf``: the measured map and its confidence over the ROI; ``ok``: the usable pixels
    (measured, above the far floor, confident: :func:`.nearest.usable`); ``n_valid``/``valid_fraction``: how
    many, and their share of the ROI."""

    result: DisparityResult
    disp: np.ndarray
    conf: np.ndarray | None
    ok: np.ndarray
    n_valid: int
    valid_fraction: float
    obj: NearestObject | None = None                     # the nearest object (stage "nearest object")
    quality: int = 0                                     # its signal quality (stage "quality floor")
    bbox: tuple[int, int, int, int] | None = None        # its box in the image (stage "quality floor")
    reading: Measurement | None = None                   # the distance read ("reading"; "fine pass" may replace it)
