"""What a reading can say: the range limits DISTANCE_SENSOR states, and the constants that set them.

The numbers behind each value are on docs/ranging.md (section named beside it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uav_depth.core.errors import ConfigError
from uav_depth.core.roi import center_roi

#: Floor of the disparity uncertainty, matched px. SGBM's sub-pixel estimate is pulled toward whole pixels
#: ("pixel locking": coherent errors up to 0.45 px over a whole branch on the synthetic scenes), so even a
#: perfectly tight cluster is only known to about +-0.5 px; a uniform error of that width has sigma 1/sqrt(12).
PIXEL_LOCKING_SIGMA_PX = 1.0 / math.sqrt(12.0)
#: The largest sigma DISTANCE_SENSOR's ``covariance`` (uint8 cm^2, 255 = unknown) can carry: 15.9 cm.
WIRE_SIGMA_MAX_M = math.sqrt(254.0) / 100.0
#: The last share of the search is not a measurement: the minimum range stated (``RangeLimits.min_distance_m``,
#: the wire's ``min_distance``) lies this share of the largest disparity before the search's end, and a reading
#: nearer than it is too close (rule 8). An object nearer than the search is matched falsely, and not always at
#: the very end: on the near sweep such twigs read within 1.046 x the search's end distance (docs/ranging.md,
#: *Too close*, rule 8). 5 % covers them, for 1.5 cm of the flight file's range at 1280x720 (0.294 m against
#: 0.279 m).
NEAR_END_BAND = 0.05
#: A weak reading this near is too close (rules 6 and 7): the thin guard's unconfident object, or a frame below
#: the quality floor, reading nearer than this many times the search's end distance (``Setup.search_end_m``,
#: where the factor was measured). A twig inside the minimum range is matched, falsely and with little
#: confidence, just beyond it, and its false matches pass the left-right check too. 1.4 is where the near sweep
#: sends none of the flight file's leafy frames inside the minimum range as a distance, and where the in-range
#: frames it turns too close have their truth within 1.35 x (docs/ranging.md, *Too close*, rules 6 and 7).
WEAK_TOO_CLOSE_FACTOR = 1.4


@dataclass(frozen=True)
class RangeLimits:
    """What the sensor can report, for DISTANCE_SENSOR: distances in m, fields of view of the ROI in rad."""

    min_distance_m: float
    max_distance_m: float
    hfov_rad: float
    vfov_rad: float
    precise_max_m: float | None = None    # where the sigma floor reaches ranging.max_sigma_m (None: nowhere)

    @property
    def stated_max_m(self) -> float:
        """DISTANCE_SENSOR's range: ``max_distance_m``, or nearer where readings stop being precise."""
        return self.max_distance_m if self.precise_max_m is None else min(self.max_distance_m, self.precise_max_m)


def default_roi(width: int, height: int) -> tuple[int, int, int, int]:
    """The central third of the image (:func:`uav_depth.core.roi.center_roi`, as the simulator's)."""
    return center_roi(width, height)


def resolve_roi(roi: tuple[int, int, int, int] | None, width: int, height: int) -> tuple[int, int, int, int]:
    """The configured ROI checked against the image size, or the default one."""
    if roi is None:
        return default_roi(width, height)
    x0, y0, x1, y1 = roi
    if x1 > width or y1 > height:
        raise ConfigError("ranging.roi", f"must lie inside the {width}x{height} rectified image", list(roi))
    return roi


def fov(a0: int, a1: int, c: float, f: float) -> float:
    """Angle subtended by pixel columns (or rows) a0..a1-1, rad (pixel edges at +-0.5)."""
    return math.atan((a1 - 0.5 - c) / f) - math.atan((a0 - 0.5 - c) / f)
