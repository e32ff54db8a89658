"""What one calibration, ROI and parameter set fix for every frame: the search in input pixels, the far floor,
the sigma floor and the range limits stated on the wire. Built (and checked) once; every stage reads it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import StereoParams
from uav_depth.core.ranging.config import RangingConfig
from uav_depth.core.ranging.limits import NEAR_END_BAND, PIXEL_LOCKING_SIGMA_PX, RangeLimits, fov


@dataclass(frozen=True)
class Setup:
    """The ranging of one calibration, ROI and parameter set (rebuilt on a parameter swap).

    ``calibration`` is the *rectified* calibration; ``roi`` (x0, y0, x1, y1) px. Derived
    at construction: ``fb`` (f x B, px m); ``px``: input pixels per matched pixel
    (with ``compute.scale`` < 1 SGBM counts matched pixels; disparities come back in
    input pixels); ``d_max``: the largest disparity the search returns, input px;
    ``d_floor``: the smallest disparity measured (farther than ``max_distance_m`` or
    than the search is no measurement); ``sigma_floor_px`` and ``d_precise``: the
    disparity uncertainty floor and the disparity where it reaches ``max_sigma_m``;
    ``search_end_m``: where the search ends, m; ``limits``: what DISTANCE_SENSOR states.
    """

    config: RangingConfig
    calibration: Calibration
    roi: tuple[int, int, int, int]
    params: StereoParams
    fb: float = field(init=False)
    px: float = field(init=False)
    d_max: float = field(init=False)
    d_floor: float = field(init=False)
    sigma_floor_px: float = field(init=False)
    d_precise: float = field(init=False)
    search_end_m: float = field(init=False)
    limits: RangeLimits = field(init=False)

    def __post_init__(self) -> None:
        config, calibration, roi, params = self.config, self.calibration, self.roi, self.params
        fb = calibration.focal_px * calibration.baseline_m
        sg = params.sgbm
        px = 1.0 / params.compute.scale
        d_max = (sg.min_disparity + sg.num_disparities - 1) * px
        if d_max <= 0:
            raise ConfigError("sgbm.num_disparities", "must reach positive disparities for ranging",
                              sg.num_disparities)
        d_floor = max(fb / config.max_distance_m, sg.min_disparity * px, 1.0 / 16.0)
        # DISTANCE_SENSOR's range ends where sigma_z = z^2 / fb * sigma_d passes max_sigma_m at the floor:
        # the fine pass's (full resolution) when it runs, the coarse pass's otherwise.
        sigma_floor_px = PIXEL_LOCKING_SIGMA_PX * (1.0 if params.compute.fine_pass else px)
        d_precise = math.sqrt(fb * sigma_floor_px / config.max_sigma_m)
        limits = RangeLimits(min_distance_m=fb / (d_max * (1.0 - NEAR_END_BAND)), max_distance_m=fb / d_floor,
                             precise_max_m=fb / d_precise,
                             hfov_rad=fov(roi[0], roi[2], calibration.principal_point[0], calibration.focal_px),
                             vfov_rad=fov(roi[1], roi[3], calibration.principal_point[1], calibration.focal_px))
        for name, value in (("fb", fb), ("px", px), ("d_max", d_max), ("d_floor", d_floor),
                            ("sigma_floor_px", sigma_floor_px), ("d_precise", d_precise),
                            ("search_end_m", fb / d_max), ("limits", limits)):
            object.__setattr__(self, name, value)
