"""The ``ranging:`` section of the run config: how the nearest object is found and when an estimate is too old."""

from __future__ import annotations

from dataclasses import dataclass

from uav_depth.core.keys import Key
from uav_depth.core.ranging.limits import WEAK_TOO_CLOSE_FACTOR, WIRE_SIGMA_MAX_M
from uav_depth.core.significant import SIGNIFICANT_AREA_M2

#: Thin guard's default area, m^2 (4 cm^2, twice a significant object's): on the leafy near sweep, smaller areas
#: let needle clouds read as the obstacle and larger ones kept more twigs out (docs/ranging.md, *Thin guard*).
THIN_GUARD_M2 = 4e-4


@dataclass(frozen=True)
class RangingConfig:
    """The ``ranging:`` section: how the nearest object is found and when an estimate is too old."""

    roi: tuple[int, int, int, int] | None = None
    min_valid_px: int = 25
    min_object_m2: float = SIGNIFICANT_AREA_M2
    min_quality: int = 31
    min_confidence: float = 0.5
    max_age_ms: float = 300.0
    max_distance_m: float = 10.0
    cluster_depth_m: float = 0.05
    surface_quantile: float = 0.2
    max_jump_rel: float = 0.2
    confirm_frames: int = 2
    max_sigma_m: float = WIRE_SIGMA_MAX_M
    thin_guard_m2: float = THIN_GUARD_M2

    KEYS = (
        Key("roi", "roi", None, "region of interest in the rectified left image, px; null: the central third",
            optional=True),
        Key("min_valid_px", "int", 25, "fewest matched pixels (at compute.scale) the nearest object needs to count "
            "(5 x 5; with min_object_m2, the area rule that dominates near the camera)", 1, 10_000_000),
        Key("min_object_m2", "float", SIGNIFICANT_AREA_M2,
            "smallest visible area, m^2 at its measured depth, that the nearest object needs to count "
            "(2 cm^2: a twig the saw or a propeller would hit)", 0.0, 1.0),
        Key("min_quality", "int", 31, "readings of lower signal quality (2..100) are no measurement, or too close "
            f"when they read within {WEAK_TOO_CLOSE_FACTOR:g} x the minimum range (docs/ranging.md: wrong readings "
            "scored 2-30, correct ones 39-85)", 0, 100),
        Key("min_confidence", "float", 0.5, "WLS confidence (0..1) a measured pixel needs to be used", 0.0, 1.0),
        Key("max_age_ms", "float", 300.0,
            "an estimate older than this (from frame capture) is never sent as valid; "
            "ArduPilot drops a rangefinder after 500 ms", 1.0, 500.0, hi_open=True),
        Key("max_distance_m", "float", 10.0, "farthest distance reported; farther objects count as no measurement",
            0.05, 600.0),
        Key("cluster_depth_m", "float", 0.05, "depth band behind the nearest surface that belongs to the same object",
            0.001, 5.0),
        Key("surface_quantile", "float", 0.2,
            "share of the object's confident pixels nearer than the reported surface: 0.5 is the object's "
            "median depth, lower reads its nearest surface (what the pruning tool meets)", 0.0, 0.5),
        Key("max_jump_rel", "float", 0.2, "a change larger than this fraction is held back until confirmed "
            "(single-frame outlier rejection); 0 disables", 0.0, 10.0),
        Key("confirm_frames", "int", 2, "consecutive agreeing frames that confirm a jump", 1, 100),
        Key("max_sigma_m", "float", WIRE_SIGMA_MAX_M, "a reading less precise (1 sigma, m) is no measurement and "
            f"DISTANCE_SENSOR's range ends where the sigma floor reaches it; default {WIRE_SIGMA_MAX_M:.4f}, the most "
            "its covariance can carry (larger: such readings go out with covariance 255, unknown)", 0.001, 100.0),
        Key("thin_guard_m2", "float", THIN_GUARD_M2, "thin guard: matched pixels that pass the left-right check but "
            "not min_confidence (a thin twig is all depth edge) make the reading nearer, or too close, when they form "
            "an object of at least this visible area, m^2 (0: off; docs/ranging.md: far fewer readings farther than "
            "a twig, more read nearer, at needles)", 0.0, 1.0),
    )
