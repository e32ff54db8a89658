"""Branch ranging: from a disparity result to the distance of the nearest significant object in the ROI.

Only pixels the matcher really measured are used (``DisparityResult.measured``,
not WLS fill-in), and only where the left-right confidence is at least
``min_confidence``. Among them, the nearest significant object is found in
disparity (docs/ranging.md says why each rule and threshold is what it is):

1. ``front``: the nearest disparity at which the pixels at least as near make at
   least ``min_valid_px`` matched pixels and ``min_object_m2`` of visible area
   (:mod:`uav_depth.core.significant`), so that stray near pixels cannot pull it
   forward at any range or ``compute.scale``;
2. the object: every pixel between ``front`` and the disparity of a surface
   ``cluster_depth_m`` behind it, widened by one matched pixel for matching noise;
3. its disparity: the confidence-weighted quantile that leaves ``surface_quantile``
   of the object nearer; its spread sigma_d: 1.4826 x the weighted median absolute
   deviation, at least 1/sqrt(12) matched px (SGBM's pixel locking). The same quantile
   is also taken in a window around the object's front pixels, and the nearer of the two
   is read: a slanted object (a branch seen obliquely) is read at its near end, not across
   its whole band.

Z = f*B/d and sigma_Z = Z^2/(f*B) * sigma_d. A reading below ``min_quality`` is no
measurement, or too close when it reads within :data:`WEAK_TOO_CLOSE_FACTOR` x the
search's end distance (a twig inside it matched weakly just beyond). With a fine pass
(``compute.fine_disparities``) the object's box is re-matched at full resolution and
ranged again by the same rules; the fine reading
replaces the coarse one when it is nearer, or farther only within half a coarse pixel
and at least as tight (``Ranger._refine``): never farther than the coarse pass saw on
a fine match that does not hold up.

With the thin guard (``ranging.thin_guard_m2``), matched pixels that pass the
left-right check but not ``min_confidence`` (a thin twig is all depth edge) may make
the reading nearer, or too close, never farther (``Ranger._thin_guard``).

An object nearer than the minimum range (the near check sees it beyond the search,
the object piles at the search's end, or it reads in the search's last
:data:`NEAR_END_BAND`, which the minimum range leaves out) is *too close*: no
distance, never a farther one. :class:`OutlierGate` lets a nearer reading through
at once and holds a jump away until ``confirm_frames`` frames agree.

Longer than 400 lines because the ranging rules (object, fine pass, too close), the
outlier gate and the records they share are one safety argument, read together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityResult
from uav_depth.core.errors import ConfigError
from uav_depth.core.keys import Key
from uav_depth.core.params import StereoParams
from uav_depth.core.roi import center_roi
from uav_depth.core.significant import SIGNIFICANT_AREA_M2

#: Disparity margin around the object's depth band, matched px: SGBM's typical matching noise.
CLUSTER_MARGIN_PX = 1.0
#: Floor of the disparity uncertainty, matched px. SGBM's sub-pixel estimate is pulled toward whole
#: pixels ("pixel locking", seen on the synthetic scenes as coherent errors up to 0.45 px over a
#: whole branch), so even a perfectly tight cluster is only known to about +-0.5 px: a uniform
#: error of that width has sigma 1/sqrt(12).
PIXEL_LOCKING_SIGMA_PX = 1.0 / math.sqrt(12.0)
#: The largest sigma DISTANCE_SENSOR's ``covariance`` (uint8 cm^2, 255 = unknown) can carry: 15.9 cm.
WIRE_SIGMA_MAX_M = math.sqrt(254.0) / 100.0
#: Too close by the near pass (:mod:`uav_depth.core.disparity.near`): at least this share of the ROI
#: matched beyond the main search, left-right consistent (since 2026-12-05; confident before). Measured with
#: the flight file (docs/ranging.md): branches at 0.08-0.27 m give 0.21-0.74, frames with nothing nearer than
#: the minimum range at most 0.06.
NEAR_BEYOND_SHARE = 0.15
#: ... or at least this share matched beyond the main search where the main pass has no confident match, if
#: those are at least NEAR_UNCONFIRMED_RATIO of the near pass's matches beyond it (a twig in front; false near
#: matches on a repeating background lie where the main pass matched confidently). Measured
#: (docs/ranging.md): twigs 0.13-0.28 m away 3.4-14 % at ratios 0.83-0.99, frames with nothing inside the
#: minimum range at most 0.9 % at a ratio above 0.75 (1.6 % at 0.36); the manual baseline's 1.8 cm branch at
#: 0.30 m (bright exposure) 1.9 % at 1.0, sent as a valid 0.53 m under the 2 % this was before 2026-12-04.
#: 1.5 % of the region is 2.4 cm^2 at the flight file's minimum range, over a significant object's 2 cm^2.
#: Kept when the near pass began to search from 0 and these counted left-right-consistent matches
#: (2026-12-05): needles then reach 1.6-2.4 % within 1.42 x the minimum range (docs/ranging.md).
NEAR_UNCONFIRMED_SHARE = 0.015
NEAR_UNCONFIRMED_RATIO = 0.75
#: A frame that measures (almost) nothing right after a too-close one is still too close: the object
#: that was nearer than the minimum range now fills the view, texture-less (docs/ranging.md).
BLANK_VALID_FRACTION = 0.1
#: ... and so is one that matches under BLANK_VALID_FRACTION of the ROI, and of its textured pixels, at any
#: disparity either pass searches while at least this share of the ROI is textured in both views
#: (:func:`uav_depth.core.disparity.near.textured`): nearer than the near pass can see (a few cm), the
#: object's other view lies outside the right image. Measured (docs/ranging.md): such frames 1.8-53 %
#: textured, 0-7 % matched; every frame with something in range matched at least 14 % of its ROI.
TEXTURED_SHARE = 0.01
#: The fine pass (``compute.fine_disparities``) searches from this share of its range below the coarse
#: disparity: most of it above, where a coarse reading that was too far (the unsafe error) finds its object.
FINE_BELOW_REL = 0.25
#: The fine object's band is widened by this much for matching noise, input px (the coarse pass: one
#: matched px). Full-resolution SGBM is good to a few tenths of a pixel; at 5 m and f*B = 22 px*m one
#: pixel is a metre of depth, and a wider band takes in the trunk behind the branch.
FINE_MARGIN_PX = 0.5
#: A fine reading farther than the coarse one replaces it only within this many coarse matched px: half a
#: pixel, the coarse pass's own rounding (a whole one let a leafy frame at 2.3 m read 1.2 px, 6 %, farther).
FINE_FARTHER_PX = 0.5
#: The fine pass matches at most this many input columns and rows (plus its search margins), around the
#: pixels that decide the reading: its cost stays bounded whatever the object's size (docs/ranging.md).
FINE_MAX_COLS = 160
FINE_MAX_ROWS = 96
#: ... or, for an object wider than FINE_MAX_COLS, up to twice as many columns with as many fewer rows (never
#: under this many): the same area, so that a branch seen obliquely keeps its near end in the fine pass.
FINE_MIN_ROWS = 16
#: Thin guard's default area, m^2 (4 cm^2, twice a significant object's): measured against 2-16 cm^2 on the leafy
#: near sweep (docs/ranging.md); smaller let needle clouds read as the obstacle, larger kept more twigs out.
THIN_GUARD_M2 = 4e-4
#: Thin guard (``ranging.thin_guard_m2`` > 0, ``Ranger._thin_guard``): an object of matched pixels that pass the
#: left-right check, confident or not, replaces the reading when it is nearer by more than this share...
THIN_GUARD_NEARER_REL = 0.02
#: ... and by more than this many matched px of disparity: half a pixel, the coarse pass's own rounding (as
#: FINE_FARTHER_PX); within it a coarse reading is no evidence against a fine one. One whole pixel (until 2026-12-05)
#: left the fine pass's reading of a thin twig, 2-5 % farther than the twig (its matches lean toward the background
#: beside it), against a guard reading 1.75-1.94 input px nearer. Measured (docs/ranging.md, *Thin guard*): leafy
#: near-sweep frames farther than 2 % 98 -> 63 (flight file, seeds 0-14); with no rule at all, plain frames at
#: 1.5-3 m read 5-23 % nearer.
THIN_GUARD_NEARER_PX = 0.5
#: ... and is reported too close when it reads nearer than WEAK_TOO_CLOSE_FACTOR times the search's end distance
#: (below).
#: ... and only when under this share of its pixels are confident: an object mostly confident is one the confident
#: reading saw already, and its unconfident edge pixels read a plain branch 5-7 % nearer (a 0.8 m branch at 640x360).
THIN_GUARD_MAX_CONFIDENT_SHARE = 0.5
#: ... and it passes over at most this many smaller objects in front of the one it reads (each costs one more
#: search, about 0.9 ms).
THIN_GUARD_MAX_SKIPPED = 4
#: A weak reading this near the minimum range is too close (docs/ranging.md, *Too close*, rules 6 and 7): the
#: thin guard's unconfident object, or a frame below the quality floor, reading nearer than this many times the
#: search's end distance (``Ranger.search_end_m``; the minimum range until 2026-12-05, when NEAR_END_BAND moved the
#: minimum range 5 % out and this was kept where it was measured). A twig inside the minimum range is matched,
#: falsely and with little confidence, just beyond it, and its false matches pass the left-right check too.
#: Measured on the near sweep (docs/ranging.md): the guard at 1.0 sent 16 of the flight file's 179 leafy frames
#: inside the minimum range as distances, at 1.4 none; below the floor, the frames inside the minimum range still
#: "no measurement" read 1.01-1.10 x (seeds 0-4) and 1.11-1.14 x (seeds 5-9), and in-range frames it turns too close
#: had their truth within 1.35 x.
WEAK_TOO_CLOSE_FACTOR = 1.4
#: The last share of the search is not a measurement: the minimum range stated (``RangeLimits.min_distance_m``, the
#: wire's ``min_distance``) lies this share of the largest disparity before the search's end, and a reading nearer than
#: it is too close (docs/ranging.md, *Too close*, rule 8). An object nearer than the search is matched falsely, and
#: not always at the very end (rule 2): twigs 11-18 % inside the manual baseline's search went out as valid distances
#: at 1.008-1.037 x the search's end distance (near sweep, leafy seeds 7 and 10), and every such frame seen on seeds
#: 0-14 since 2026-12-03 read within 1.046 x. 5 % covers them; it costs 1.5 cm of the flight file's range at
#: 1280x720 (0.279 -> 0.294 m).
NEAR_END_BAND = 0.05
#: A slanted object's surface is also read in a square window this many matched px a side around its
#: front pixels, where it is nearest (``Ranger._slanted_surface``; 0 turns the rule off).
FRONT_WINDOW_MATCHED_PX = 20


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



@dataclass(frozen=True)
class Measurement:
    """One frame's ranging result. ``distance_m`` is None when there is no measurement (``reason`` says why).

    ``sigma_m``: 1-sigma uncertainty of the distance; ``quality``: 2..100 from the
    valid fraction of the ROI and the object's mean confidence (1 is reserved for
    "invalid" on the wire); ``bbox``: (x0, y0, x1, y1) px of the object's pixels in
    the image; ``disparity_px``/``sigma_px``: the object's disparity and spread;
    ``n_px``: its pixel count; ``valid_fraction``: measured confident pixels / ROI area;
    ``too_close``: an object is nearer than the minimum range (``distance_m`` is then
    None: no distance was measured, but the obstacle is nearer than ``min_distance_m``);
    ``refined``: the distance, sigma, box and disparity come from the fine pass; ``guarded``: from the
    thin guard (``ranging.thin_guard_m2``), or it found the object too close.
    """

    distance_m: float | None
    sigma_m: float | None = None
    quality: int = 0
    bbox: tuple[int, int, int, int] | None = None
    disparity_px: float | None = None
    sigma_px: float | None = None
    n_px: int = 0
    valid_fraction: float = 0.0
    reason: str | None = None
    too_close: bool = False
    refined: bool = False
    guarded: bool = False

    @property
    def valid(self) -> bool:
        return self.distance_m is not None


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


#: SGBM's disparity grid (levels per px) and the most levels :func:`_weighted_quantiles` sums a histogram over.
_QUANTILE_GRID = 16.0
_QUANTILE_MAX_LEVELS = 1 << 16


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray | None, *qs: float) -> list[float]:
    """The values that leave a share q of the weight below them, for each q (one histogram or one sort);
    ``weights`` None: each value weighs 1 (the same answer as ones, counted instead of summed).

    Tied values may be ordered either way: the value where the cumulative weight crosses
    q is the same, so the sort need not be stable (it is about twice as fast).

    Disparities from the matcher usually lie on SGBM's grid of 1/16 px (the coarse pass's at half
    scale on 1/8 input px, when the crop is a whole number of matched px): then the weight is summed
    per grid level instead (a histogram, no sort; the sort was a quarter of the ranging stage's
    time, docs/performance.md), and the answer is the first level whose cumulative weight reaches
    q, the same value the sort finds. Off the grid (a crop scaled by a fraction, exact disparities)
    the sort is used."""
    if values.size:
        v64 = values.astype(np.float64, copy=False)
        lo = float(v64.min())
        keys = np.rint((v64 - lo) * _QUANTILE_GRID)
        if keys.max() < _QUANTILE_MAX_LEVELS and np.array_equal(keys / _QUANTILE_GRID + lo, v64):
            cum = np.cumsum(np.bincount(keys.astype(np.intp), weights=weights))
            return [lo + float(min(int(np.searchsorted(cum, q * cum[-1])), cum.size - 1)) / _QUANTILE_GRID
                    for q in qs]
    order = np.argsort(values)
    v = values[order]
    cum = np.arange(1, v.size + 1) if weights is None else np.cumsum(weights[order], dtype=np.float64)
    return [float(v[min(int(np.searchsorted(cum, q * cum[-1])), v.size - 1)]) for q in qs]


def _median(values: np.ndarray) -> float:
    """``np.median`` of pixel indices, the same value without its overhead on the few hundred a window centres on."""
    n = values.size
    if n > 1024:
        return float(np.median(values))
    s = np.sort(values)
    return float(s[n // 2]) if n % 2 else (float(s[n // 2 - 1]) + float(s[n // 2])) / 2.0


def _weighted_median(values: np.ndarray, weights: np.ndarray | None) -> float:
    return _weighted_quantiles(values, weights, 0.5)[0]


class Ranger:
    """The ranging stage for one calibration, ROI and parameter set (rebuilt on a parameter swap).

    ``calibration`` is the *rectified* calibration; ``roi`` (x0, y0, x1, y1) px.
    """

    def __init__(self, config: RangingConfig, calibration: Calibration, roi: tuple[int, int, int, int],
                 params: StereoParams):
        self.config = config
        self.calibration = calibration
        self.roi = roi
        self.params = params
        self.fb = calibration.focal_px * calibration.baseline_m
        sg = params.sgbm
        # With compute.scale < 1 SGBM counts matched pixels; disparities come back in input pixels.
        self.px = 1.0 / params.compute.scale          # input pixels per matched pixel
        d_max = (sg.min_disparity + sg.num_disparities - 1) * self.px   # largest disparity returned, px
        self.d_max = d_max
        if d_max <= 0:
            raise ConfigError("sgbm.num_disparities", "must reach positive disparities for ranging",
                              sg.num_disparities)
        # Farther than max_distance_m (or than the smallest searched disparity) is "no measurement".
        self.d_floor = max(self.fb / config.max_distance_m, sg.min_disparity * self.px, 1.0 / 16.0)
        # DISTANCE_SENSOR's range ends where sigma_z = z^2 / fb * sigma_d passes max_sigma_m at the floor:
        # the fine pass's (full resolution) when it runs, the coarse pass's otherwise.
        self.sigma_floor_px = PIXEL_LOCKING_SIGMA_PX * (1.0 if params.compute.fine_pass else self.px)
        self.d_precise = math.sqrt(self.fb * self.sigma_floor_px / config.max_sigma_m)
        # Where the search ends, m: rules 6 and 7 (WEAK_TOO_CLOSE_FACTOR) count from here, as they were measured.
        self.search_end_m = self.fb / d_max
        self.limits = RangeLimits(min_distance_m=self.fb / (d_max * (1.0 - NEAR_END_BAND)),
                                  max_distance_m=self.fb / self.d_floor,
                                  precise_max_m=self.fb / self.d_precise,
                                  hfov_rad=_fov(roi[0], roi[2], calibration.principal_point[0],
                                                calibration.focal_px),
                                  vfov_rad=_fov(roi[1], roi[3], calibration.principal_point[1],
                                                calibration.focal_px))

    def measure(self, result: DisparityResult) -> Measurement:
        """The nearest significant object's distance in the ROI of one disparity result."""
        m = self._measure(result)
        if self.config.thin_guard_m2 > 0 and not m.too_close and result.lr_consistent is not None:
            return self._thin_guard(m, result)
        return m

    def _thin_guard(self, m: Measurement, result: DisparityResult) -> Measurement:
        """``m``, or a nearer reading from the matched pixels that pass the left-right check, confident or not.

        The confidence gives a thin twig (a few matched pixels wide, all depth edge) almost no weight, so the
        nearest confident object can be the branch or trunk behind it: read farther than the twig (the leafy
        near sweep, docs/ranging.md). Here the same rules 1-3 find the nearest object among every measured
        pixel that passes the left-right check, each weighing 1, that covers at least ``thin_guard_m2`` of
        visible area (up to :data:`THIN_GUARD_MAX_SKIPPED` smaller ones in front of it, stray consistent
        matches, are passed over); if it reads nearer than ``m`` by more than :data:`THIN_GUARD_NEARER_REL` and by more
        than :data:`THIN_GUARD_NEARER_PX` matched pixels of disparity (the coarse pass's rounding: within it, a coarse
        reading is no evidence against a fine one; without this rule the flight file's plain frames at 1.5-3 m read
        5-23 % nearer), it replaces ``m``:
        coarse, without the fine pass (whose confidence would drop the twig again) or the quality floor (it
        is the nearer reading). Nearer than :data:`WEAK_TOO_CLOSE_FACTOR` times the search's end distance, or
        piled at the search's end, it is too close, also when ``m`` has no distance; otherwise a frame without
        a distance stays without one (the guard never turns "no measurement" into a distance: on the leafy
        suite that let a +9 % reading out). Never farther than ``m``.
        """
        cfg = self.config
        x0, y0, x1, y1 = self.roi
        disp = result.measured[y0:y1, x0:x1]
        # The guard can only act through an object whose front is beyond ``need`` (nearer than m by more than
        # THIN_GUARD_NEARER_PX matched px, or within the too-close factor when m has no distance): fewer consistent
        # pixels there than an object needs, and nothing can change (most frames; the search below costs about
        # 0.9 ms on the bench frames).
        lim_d = self.fb / (WEAK_TOO_CLOSE_FACTOR * self.search_end_m)
        need = (m.disparity_px + THIN_GUARD_NEARER_PX * self.px if m.valid
                else min(lim_d, self.d_max - CLUSTER_MARGIN_PX * self.px))
        with np.errstate(invalid="ignore"):
            ok = (disp >= self.d_floor) & result.lr_consistent[y0:y1, x0:x1]
            if np.count_nonzero(ok & (disp >= need)) < cfg.min_valid_px * self.px * self.px:
                return m
        # The nearest object whose band covers thin_guard_m2: a smaller one in front (stray consistent matches on
        # sky or background at a false disparity, on the leafy sweep) is passed over, not taken as the answer.
        cand = ok
        for _ in range(THIN_GUARD_MAX_SKIPPED + 1):
            g = self._object(disp, None, cand, self.px)
            if g is None:
                return m
            z = self.fb / g.d
            area_m2 = g.n * (z / self.calibration.focal_px) ** 2
            if area_m2 >= cfg.thin_guard_m2:
                break
            with np.errstate(invalid="ignore"):
                cand = cand & (disp < g.lower)
        else:
            return m
        if m.valid and (z >= m.distance_m * (1.0 - THIN_GUARD_NEARER_REL) or g.d <= need):
            return m
        if result.confidence is not None:
            with np.errstate(invalid="ignore"):
                member = ok & (disp >= g.lower) & (disp <= g.front + CLUSTER_MARGIN_PX * self.px)
            conf = result.confidence[y0:y1, x0:x1]
            if float((conf[member] >= cfg.min_confidence).mean()) >= THIN_GUARD_MAX_CONFIDENT_SHARE:
                return m       # the confident pixels saw this object: only the weighting differs
        lim = self.search_end_m
        if g.front >= self.d_max - CLUSTER_MARGIN_PX * self.px or z < WEAK_TOO_CLOSE_FACTOR * lim:
            return Measurement(None, n_px=m.n_px, valid_fraction=m.valid_fraction, too_close=True, guarded=True,
                               reason=f"thin guard: {area_m2 * 1e4:.1f} cm^2 of left-right-consistent matches read "
                                      f"{z:.3f} m, within {WEAK_TOO_CLOSE_FACTOR:g} x the search's end "
                                      f"{lim:.3f} m or at the search's end: too close")
        if not m.valid:      # the guard makes a reading nearer or too close; it never turns "none" into a distance
            return m
        quality = int(min(100, max(2, round(100.0 * float(ok.mean())))))
        g_m = replace(self._reading(g, _shift(g.bbox, x0, y0), quality, m.valid_fraction), guarded=True)
        if g_m.sigma_m > cfg.max_sigma_m:      # nearer than m, but not precise: neither is sent
            return replace(g_m, distance_m=None, sigma_m=None,
                           reason=f"thin guard: a nearer object reads {z:.3f} m with sigma {g_m.sigma_m:.3f} m above "
                                  f"max_sigma_m {cfg.max_sigma_m:.3f} m")
        return g_m

    def _measure(self, result: DisparityResult) -> Measurement:
        """:meth:`measure` on the confident pixels alone (rules 1-3, fine pass, too close, floors)."""
        cfg = self.config
        x0, y0, x1, y1 = self.roi
        disp = result.measured[y0:y1, x0:x1]
        conf = None if result.confidence is None else result.confidence[y0:y1, x0:x1]
        ok = self._usable(disp, conf)
        n_valid = int(ok.sum())
        valid_fraction = n_valid / disp.size
        near = self._too_close(result)
        if near is not None:
            return Measurement(None, n_px=n_valid, valid_fraction=valid_fraction, reason=near, too_close=True)
        obj = self._object(disp, conf, ok, self.px)
        if obj is None:
            return Measurement(None, n_px=n_valid, valid_fraction=valid_fraction,
                               reason=f"no object of {cfg.min_valid_px} matched pixels and "
                                      f"{cfg.min_object_m2 * 1e4:g} cm^2 among the {n_valid} confident "
                                      f"measured pixels in the ROI")
        if obj.front >= self.d_max - CLUSTER_MARGIN_PX * self.px:
            # The object piles at the end of the search: it may be nearer than SGBM can tell.
            return Measurement(None, n_px=n_valid, valid_fraction=valid_fraction, too_close=True,
                               reason=f"the nearest object's disparity {obj.front:.1f} px is at the search's end "
                                      f"{self.d_max:.1f} px: nearer than {self.limits.min_distance_m:.3f} m")
        quality = int(min(100, max(2, round(100.0 * valid_fraction * obj.mean_conf))))
        bbox = _shift(obj.bbox, x0, y0)
        if quality < cfg.min_quality:
            z, lim = self.fb / obj.d, self.search_end_m
            weak_near = z < WEAK_TOO_CLOSE_FACTOR * lim      # rule 7: a weak reading at the minimum range
            why = (f"and the nearest object reads {z:.3f} m, within {WEAK_TOO_CLOSE_FACTOR:g} x the search's end "
                   f"{lim:.3f} m: too close" if weak_near else f"(the object would read {z:.3f} m)")
            return Measurement(None, quality=quality, bbox=bbox, disparity_px=obj.d, sigma_px=obj.sigma_d,
                               n_px=obj.n, valid_fraction=valid_fraction, too_close=weak_near,
                               reason=f"signal quality {quality} below min_quality {cfg.min_quality} {why}")
        m = self._reading(obj, bbox, quality, valid_fraction)
        if result.fine is not None:
            m = self._refine(m, obj, result, disp, ok)
        # Decided on the reading that would go out (the fine one when it stands): it is the one sent.
        if m.distance_m < self.limits.min_distance_m:     # rule 8: the search's last NEAR_END_BAND
            return replace(m, distance_m=None, sigma_m=None, refined=False, too_close=True,
                           reason=f"the nearest object reads {m.distance_m:.3f} m, in the search's last "
                                  f"{NEAR_END_BAND * 100:g} % (where an object nearer than the search is matched "
                                  f"falsely): nearer than the minimum range {self.limits.min_distance_m:.3f} m")
        if m.sigma_m > cfg.max_sigma_m:
            return replace(m, distance_m=None, sigma_m=None, refined=False,
                           reason=f"sigma {m.sigma_m:.3f} m above max_sigma_m {cfg.max_sigma_m:.3f} m "
                                  f"(the object would read {m.distance_m:.3f} m)")
        return m

    def _reading(self, obj: "_Object", bbox: tuple[int, int, int, int], quality: int, valid_fraction: float,
                 refined: bool = False) -> Measurement:
        z = self.fb / obj.d
        return Measurement(distance_m=z, sigma_m=z * z / self.fb * obj.sigma_d, quality=quality, bbox=bbox,
                           disparity_px=obj.d, sigma_px=obj.sigma_d, n_px=obj.n, valid_fraction=valid_fraction,
                           refined=refined)

    def _usable(self, disp: np.ndarray, conf: np.ndarray | None) -> np.ndarray:
        """Measured pixels above the far floor and (with a confidence map) confident enough."""
        with np.errstate(invalid="ignore"):     # NaN compares False: unmatched pixels drop out
            ok = disp >= self.d_floor
            if conf is not None:
                ok &= conf >= self.config.min_confidence
        return ok

    def _object(self, disp: np.ndarray, conf: np.ndarray | None, ok: np.ndarray, px: float,
                count_px: float | None = None, margin_px: float | None = None,
                slant_cap: float | None = None) -> "_Object | None":
        """The nearest significant object among the ``ok`` pixels of a map matched at ``px`` input px per
        matched px (rules 1-3 of the module docstring); None if there is none. ``count_px``: the matched
        pixel ``min_valid_px`` counts, input px across (default ``px``; the fine pass counts the coarse
        pass's, so that its object covers the same image area); ``margin_px``: the band's widening for
        matching noise, input px (default one matched pixel)."""
        cfg = self.config
        vals = disp[ok]
        front = self._front(vals, px, px if count_px is None else count_px)
        if front is None:
            return None
        margin = CLUSTER_MARGIN_PX * px if margin_px is None else margin_px
        lower = self.fb / (self.fb / front + cfg.cluster_depth_m) - margin
        upper = front + margin
        with np.errstate(invalid="ignore"):
            mask = ok & (disp >= lower) & (disp <= upper)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        bbox = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
        box = (slice(bbox[1], bbox[3]), slice(bbox[0], bbox[2]))
        # Every object pixel lies in its box: read there, in row order (what the ROI-wide indexing gave, cheaper).
        inbox, dbox = mask[box], disp[box]
        wbox = conf[box] if conf is not None else None
        v = dbox[inbox].astype(np.float64)
        w = wbox[inbox].astype(np.float64) if wbox is not None else None     # None: each pixel weighs 1
        if w is not None and not w.sum() > 0:
            w, wbox = None, None
        # Larger disparity is nearer: leave surface_quantile of the object's weight above d.
        d, med = _weighted_quantiles(v, w, 1.0 - cfg.surface_quantile, 0.5)
        sigma_d = max(1.4826 * _weighted_median(np.abs(v - med), w), PIXEL_LOCKING_SIGMA_PX * px)
        d = self._slanted_surface(inbox, dbox, wbox, front, d, front if slant_cap is None else min(front, slant_cap),
                                  px if count_px is None else count_px)
        return _Object(front, d, sigma_d, int(v.size), float(w.mean()) if w is not None else 1.0, lower, bbox)

    def _slanted_surface(self, mask: np.ndarray, disp: np.ndarray, weight: np.ndarray | None, front: float,
                         d: float, cap: float, count_px: float) -> float:
        """The object's reported disparity ``d``, read again where the object is nearest.

        The quantile over the whole band reads a branch seen obliquely (braking pitch, yaw)
        near its middle, farther than its near end: up to 7 % on the SITL scene at 7 degrees.
        So the same quantile is also taken over the object's pixels in a square window
        (:data:`FRONT_WINDOW_MATCHED_PX` matched px a side) centred on the median position
        of its front pixels (those at least as near as ``front``): on a slanted object they
        gather at its near end, on a level one they scatter along it and the window sits in
        its middle. The window's reading wins when it is nearer and the window holds at
        least ``min_valid_px`` matched pixels of the object. Never farther than ``d``, never
        nearer than ``cap`` (the front; for the fine pass the coarse pass's front if that is
        farther). ``mask``: the object's pixels in its box; ``disp`` and ``weight`` (None:
        each pixel weighs 1): the map and the weights over the same box.
        """
        if FRONT_WINDOW_MATCHED_PX <= 0:
            return d
        with np.errstate(invalid="ignore"):
            ys, xs = np.nonzero(mask & (disp >= front))
        if ys.size == 0:
            return d
        half = FRONT_WINDOW_MATCHED_PX * count_px / 2.0
        cy, cx = _median(ys), _median(xs)
        # The window: the box's rows and columns within ``half`` of the centre (a slice of the box).
        r = np.flatnonzero(np.abs(np.arange(mask.shape[0]) - cy) <= half)
        c = np.flatnonzero(np.abs(np.arange(mask.shape[1]) - cx) <= half)
        if r.size == 0 or c.size == 0:
            return d
        win = (slice(int(r[0]), int(r[-1]) + 1), slice(int(c[0]), int(c[-1]) + 1))
        inside = mask[win]
        if np.count_nonzero(inside) < self.config.min_valid_px * count_px * count_px:
            return d
        v = disp[win][inside].astype(np.float64)
        w = weight[win][inside].astype(np.float64) if weight is not None else None
        (near_end,) = _weighted_quantiles(v, w, 1.0 - self.config.surface_quantile)
        return min(max(near_end, d), max(d, cap))

    def _refine(self, m: Measurement, obj: "_Object", result: DisparityResult, disp: np.ndarray,
                ok: np.ndarray) -> Measurement:
        """The coarse reading ``m`` re-measured on the fine pass (:mod:`uav_depth.core.disparity.fine`).

        The object's box (one coarse pixel more all round, inside the ROI) is matched at
        full resolution from :data:`FINE_BELOW_REL` of the search below the coarse
        disparity. Every pixel counts except those the coarse pass measured confidently
        behind the object: measured at the object's depth or nearer, measured with low
        confidence, or not measured at all (a thin twig in front is often lost at half
        scale, or matched there with the low confidence the depth-edge weight gives a
        pixel that is all edge; so are the columns SGBM leaves unanswered). The narrow
        search would match the background around a thin branch to something inside it,
        and without a right matcher nothing in the fine pass tells such a match from a
        true one.
        Fine pixels at the search's lower end (farther than searched) do not count
        either. The fine object (its front and its own band) needs as many pixels as a
        coarse one (``min_valid_px`` coarse matched pixels): the same image area, not a
        smaller speckle.

        The fine object replaces the coarse one when it is nearer (nearer is always
        safe), or farther but confident: within half a coarse matched pixel of the
        coarse disparity (the coarse pass's own rounding) and measured at least as
        tightly (its spread sigma_d no larger). Otherwise the coarse reading stands:
        never farther than what the coarse pass saw on a fine match that does not hold
        up.
        """
        assert result.fine is not None
        x0, y0, x1, y1 = self.roi
        pad = int(math.ceil(self.px))
        bx0, by0, bx1, by1 = obj.bbox
        bx0, by0, bx1, by1 = max(0, bx0 - pad), max(0, by0 - pad), min(x1 - x0, bx1 + pad), min(y1 - y0, by1 + pad)
        # Columns beside the box where the coarse pass measured nothing at all in the box's rows (e.g. the
        # band SGBM leaves unanswered at the image's left edge, wider than the object's own disparity
        # needs) may hold a nearer part of the object: the fine pass looks there too.
        seen = np.isfinite(disp[by0:by1]).any(axis=0)
        ox0, ox1 = bx0, bx1
        while bx0 > 0 and not seen[bx0 - 1]:
            bx0 -= 1
        while bx1 < seen.size and not seen[bx1]:
            bx1 += 1
        # The window keeps the unseen columns (the side they are on), else centres on the front pixels.
        anchor = "left" if bx0 < ox0 else "right" if bx1 > ox1 else None
        with np.errstate(invalid="ignore"):
            front = ok[by0:by1, bx0:bx1] & (disp[by0:by1, bx0:bx1] >= obj.d)
        bx0, by0, bx1, by1 = self._fine_window((bx0, by0, bx1, by1), front, anchor)
        num = self.params.compute.fine_disparities
        d0 = max(0, int(math.floor(obj.d - FINE_BELOW_REL * num)))
        fm = result.fine((bx0 + x0, by0 + y0, bx1 + x0, by1 + y0), d0)
        if fm is None:
            return m
        box = (slice(by0, by1), slice(bx0, bx1))
        with np.errstate(invalid="ignore"):
            mine = ~(ok[box] & (disp[box] < obj.lower))      # all but what the coarse pass saw confidently behind
            fok = self._usable(fm.measured, fm.confidence) & (fm.measured >= fm.d_lo + 1.0) & mine
        fobj = self._object(fm.measured, fm.confidence, fok, 1.0, self.px, FINE_MARGIN_PX, slant_cap=obj.front)
        if fobj is None or fobj.n < self.config.min_valid_px * self.px * self.px:
            return m
        if fobj.d < obj.d and not (obj.d - fobj.d <= FINE_FARTHER_PX * self.px and fobj.sigma_d <= obj.sigma_d):
            return m
        return self._reading(fobj, _shift(fobj.bbox, bx0 + x0, by0 + y0), m.quality, m.valid_fraction, refined=True)

    @staticmethod
    def _fine_window(box: tuple[int, int, int, int], front: np.ndarray,
                     anchor: str | None = None) -> tuple[int, int, int, int]:
        """``box`` (ROI coordinates) cut to at most FINE_MAX_COLS x FINE_MAX_ROWS (a wider box: up to twice the
        columns with the rows cut to keep the area, at least FINE_MIN_ROWS) around the median of the
        ``front`` pixels in it (those that decide the reading), or along the ``anchor`` side ("left",
        "right"): the fine pass's cost stays bounded. ``front``: the box's own pixels."""
        bx0, by0, bx1, by1 = box
        ys, xs = np.nonzero(front)
        if ys.size == 0:
            return box
        cx, cy = bx0 + int(_median(xs)), by0 + int(_median(ys))
        if anchor == "left":
            cx = bx0 + FINE_MAX_COLS // 2
        elif anchor == "right":
            cx = bx1 - FINE_MAX_COLS // 2

        def cut(lo: int, hi: int, c: int, n: int) -> tuple[int, int]:
            if hi - lo <= n:
                return lo, hi
            start = min(max(lo, c - n // 2), hi - n)
            return start, start + n

        cols = max(FINE_MAX_COLS, min(bx1 - bx0, 2 * FINE_MAX_COLS))
        rows = max(FINE_MIN_ROWS, min(FINE_MAX_ROWS, (FINE_MAX_COLS * FINE_MAX_ROWS) // cols))
        (bx0, bx1), (by0, by1) = cut(bx0, bx1, cx, cols), cut(by0, by1, cy, rows)
        return bx0, by0, bx1, by1

    def _front(self, vals: np.ndarray, px: float, count_px: float) -> float | None:
        """The nearest disparity (px) at which the pixels at least as near form a significant object:
        at least ``min_valid_px`` matched pixels (of ``count_px`` input px across; disparities matched at
        ``px`` input px per matched px) and ``min_object_m2`` of visible area; None if none."""
        if vals.size == 0:
            return None
        cfg = self.config
        # Disparities in 1/16 matched px (SGBM's own resolution), counted from the nearest down.
        q = np.rint(vals * (16.0 / px)).astype(np.int64)
        counts = np.bincount(q)
        levels = np.arange(counts.size) * (px / 16.0)
        with np.errstate(divide="ignore"):
            px_area = np.where(levels > 0, (self.calibration.baseline_m / np.maximum(levels, 1e-9)) ** 2, 0.0)
        n_near = np.cumsum(counts[::-1])[::-1] / (count_px * count_px)   # matched pixels at or nearer
        a_near = np.cumsum((counts * px_area)[::-1])[::-1]                # m^2 at or nearer
        hit = np.flatnonzero((n_near >= cfg.min_valid_px) & (a_near >= cfg.min_object_m2))
        if hit.size == 0:
            return None
        return float(vals[q >= hit[-1]].min())

    def _too_close(self, result: DisparityResult) -> str | None:
        """Why the region holds an object nearer than the minimum range, or None (docs/ranging.md)."""
        near = result.near
        if near is None:
            return None
        x0, y0, x1, y1 = self.roi
        cfg = self.config
        nd = near.disparity[y0:y1, x0:x1]
        with np.errstate(invalid="ignore"):
            # Rules 1 and 3 on the near pass's left-right check alone: at its coarse scale a branch a few pixels
            # wide is all depth edge, and the confidence's roll-off weighs it 0 (docs/ranging.md, rule 1).
            near_found = np.isfinite(nd)
            if result.near_consistent is not None:
                near_found &= result.near_consistent[y0:y1, x0:x1]
            beyond = near_found & (nd > self.d_max)
        share = float(beyond.mean()) if beyond.size else 0.0
        if share >= NEAR_BEYOND_SHARE:
            b = nd[beyond]
            return (f"the near pass matches {share:.0%} of the ROI at disparities {np.median(b):.0f} px (median), "
                    f"beyond the search's {self.d_max:.0f} px: nearer than {self.limits.min_distance_m:.3f} m")
        main = None

        def main_matched() -> np.ndarray:
            # The main pass's confident matches at any disparity it searches (the far floor does not apply).
            with np.errstate(invalid="ignore"):
                m = np.isfinite(result.measured[y0:y1, x0:x1])
                if result.confidence is not None:
                    m &= result.confidence[y0:y1, x0:x1] >= cfg.min_confidence
            return m

        if share >= NEAR_UNCONFIRMED_SHARE:
            # A smaller near object (a twig in front): the near pass's matches beyond the search where the main
            # pass has no confident match of its own (where it has one, the near match is the false one).
            main = main_matched()
            unconfirmed = beyond & ~main
            u_share = float(unconfirmed.mean())
            if u_share >= NEAR_UNCONFIRMED_SHARE and unconfirmed.sum() >= NEAR_UNCONFIRMED_RATIO * beyond.sum():
                b = nd[unconfirmed]
                return (f"the near pass matches {u_share:.1%} of the ROI at disparities {np.median(b):.0f} px "
                        f"(median), beyond the search's {self.d_max:.0f} px, where the main pass matches nothing "
                        f"confidently: nearer than {self.limits.min_distance_m:.3f} m")
        if near.textured is None:
            return None
        # Rule 4 on the near pass's confident matches (docs/ranging.md, rule 1 says why not its left-right check).
        # The main pass's alone first: when they already pass, so does the union, and the near pass's confidence
        # (computed when asked for) is not needed.
        main = main_matched() if main is None else main
        if main.mean() >= BLANK_VALID_FRACTION:
            return None
        near_ok = np.isfinite(nd)
        if near.confidence is not None:
            near_ok &= near.confidence()[y0:y1, x0:x1] >= cfg.min_confidence
        matched = near_ok | main
        m_all = float(matched.mean())
        if m_all >= BLANK_VALID_FRACTION:
            return None
        # Blank: is it textured (an object nearer than either search) or not (sky, a bare wall)?
        tex = near.textured()[y0:y1, x0:x1]
        tex_share = float(tex.mean()) if tex.size else 0.0
        if tex_share >= TEXTURED_SHARE and float(matched[tex].mean()) < BLANK_VALID_FRACTION:
            return (f"{tex_share:.0%} of the ROI is textured in both views but neither pass matches it at any "
                    f"disparity it searches ({m_all:.0%} of the ROI matched): an object nearer than either search "
                    f"fills the view, nearer than {self.limits.min_distance_m:.3f} m")
        return None


@dataclass(frozen=True)
class _Object:
    """The nearest significant object of one map: ``front`` disparity, reported disparity ``d`` and its
    spread ``sigma_d`` (input px), pixel count ``n`` (input px), mean confidence, the band's lower
    disparity ``lower``, and ``bbox`` (x0, y0, x1, y1) in the map's own coordinates."""

    front: float
    d: float
    sigma_d: float
    n: int
    mean_conf: float
    lower: float
    bbox: tuple[int, int, int, int]


def _shift(box: tuple[int, int, int, int], dx: int, dy: int) -> tuple[int, int, int, int]:
    return box[0] + dx, box[1] + dy, box[2] + dx, box[3] + dy


def _fov(a0: int, a1: int, c: float, f: float) -> float:
    """Angle subtended by pixel columns (or rows) a0..a1-1, rad (pixel edges at +-0.5)."""
    return math.atan((a1 - 0.5 - c) / f) - math.atan((a0 - 0.5 - c) / f)


@dataclass
class OutlierGate:
    """Single-frame outlier rejection over successive measurements, asymmetric.

    A nearer distance is accepted at once, whatever the jump: for a drone closing
    on a branch, a sudden nearer object must win now, and holding it back would
    keep sending the older, farther distance. A distance *farther* than the last
    accepted one by more than ``max_jump_rel`` (relative) is held back; it is
    accepted once ``confirm_frames`` consecutive frames agree with each other within
    that tolerance. After ``forget_s`` without an accepted measurement the history
    is forgotten (the next one is accepted). :meth:`too_close` records a frame
    reported too close as the nearest distance, so that a jump away from it needs
    confirming too.
    """

    max_jump_rel: float
    confirm_frames: int
    forget_s: float = 1.0
    _last: float | None = None
    _last_t: float = -math.inf
    _pending: list[float] = field(default_factory=list)
    _too_close_t: float = -math.inf

    def accept(self, distance_m: float, t: float) -> bool:
        if self.max_jump_rel <= 0 or self._last is None or t - self._last_t > self.forget_s:
            return self._take(distance_m, t)
        if distance_m - self._last <= self.max_jump_rel * self._last:     # nearer, or not much farther
            return self._take(distance_m, t)
        if self._pending and abs(distance_m - self._pending[-1]) > self.max_jump_rel * self._pending[-1]:
            self._pending = []
        self._pending.append(distance_m)
        if len(self._pending) >= self.confirm_frames:
            return self._take(distance_m, t)
        return False

    def too_close(self, min_distance_m: float, t: float) -> None:
        """A frame found the object nearer than ``min_distance_m``: the nearest possible reading."""
        self._take(min_distance_m, t)
        self._too_close_t = t

    def near(self, m: Measurement, min_distance_m: float, t: float) -> Measurement:
        """Book a too-close measurement; keep a blank frame right after one too close.

        A frame that measures almost nothing (valid fraction under
        :data:`BLANK_VALID_FRACTION`) within ``forget_s`` of a too-close one is too
        close as well: the object that came nearer than the minimum range now fills
        the view and nothing in it can be matched (seen at 0.05-0.07 m).
        """
        if m.too_close:
            self.too_close(min_distance_m, t)
            return m
        if (not m.valid and m.valid_fraction < BLANK_VALID_FRACTION and t - self._too_close_t <= self.forget_s):
            self.too_close(min_distance_m, t)
            return replace(m, too_close=True, reason=f"blank after a too-close frame ({m.reason})")
        return m

    def _take(self, distance_m: float, t: float) -> bool:
        self._last, self._last_t, self._pending = distance_m, t, []
        return True

    def reset(self) -> None:
        self._last, self._last_t, self._pending, self._too_close_t = None, -math.inf, [], -math.inf


@dataclass(frozen=True)
class Estimate:
    """What the send clock publishes: one accepted measurement of one frame.

    ``t_capture``: monotonic s of the frame's capture (age is measured from it);
    ``timings_ms``: per-stage wall times of this frame; ``truth_m``: the source's
    ground truth when it knows it; ``too_close``: an object is nearer than
    ``limits.min_distance_m`` (no distance measured; the link sends it as an
    obstacle nearer than the minimum, never as clear).
    """

    measurement: Measurement
    limits: RangeLimits
    t_capture: float
    t_done: float
    frame_index: int
    params_hash: str
    truth_m: float | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)
    too_close: bool = False

    @property
    def distance_m(self) -> float | None:
        return self.measurement.distance_m

