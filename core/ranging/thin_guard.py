"""The thin guard: matched pixels that pass the left-right check but not ``min_confidence`` (a thin twig is all
depth edge) may make the reading nearer, or too close, never farther (``ranging.thin_guard_m2``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging.floors import imprecise
from uav_depth.core.ranging.limits import WEAK_TOO_CLOSE_FACTOR
from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.nearest import CLUSTER_MARGIN_PX, NearestObject, find, reading, shift
from uav_depth.core.ranging.setup import Setup
from uav_depth.core.ranging.stats import share_of

#: The guard's object replaces the reading when it is nearer by more than this share ...
THIN_GUARD_NEARER_REL = 0.02
#: ... and by more than this many matched px of disparity: half a pixel, the coarse pass's own rounding (as
#: FINE_FARTHER_PX); within it a coarse reading is no evidence against a fine one. A thin twig's fine reading
#: leans 2-5 % toward the background beside it, about 2 input px farther than the guard's; without the rule,
#: plain frames at 1.5-3 m read 5-23 % nearer (docs/ranging.md, *Thin guard*).
THIN_GUARD_NEARER_PX = 0.5
#: ... and only when under this share of its pixels are confident: an object mostly confident is one the confident
#: reading saw already, and its unconfident edge pixels read a plain branch 5-7 % nearer (a 0.8 m branch at 640x360).
THIN_GUARD_MAX_CONFIDENT_SHARE = 0.5
#: ... and it passes over at most this many smaller objects in front of the one it reads (each costs one more
#: search, about 0.9 ms).
THIN_GUARD_MAX_SKIPPED = 4


def thin_guard(s: Setup, m: Measurement, result: DisparityResult) -> Measurement:
    """Guard: ``m``, or a nearer reading from the matched pixels that pass the left-right check, confident or not.

    The confidence gives a thin twig (a few matched pixels wide, all depth edge) almost no weight, so the
    nearest confident object can be the branch or trunk behind it: read farther than the twig (the leafy
    near sweep, docs/ranging.md). Here the same rules find the nearest object among every measured
    pixel that passes the left-right check, each weighing 1, that covers at least ``thin_guard_m2`` of
    visible area (up to :data:`THIN_GUARD_MAX_SKIPPED` smaller ones in front of it, stray consistent
    matches, are passed over); if it reads nearer than ``m`` by more than :data:`THIN_GUARD_NEARER_REL` and by
    more than :data:`THIN_GUARD_NEARER_PX` matched pixels of disparity, it replaces ``m``: coarse, without the
    fine pass (whose confidence would drop the twig again) or the quality floor (it is the nearer reading).
    Nearer than :data:`~.limits.WEAK_TOO_CLOSE_FACTOR` times the search's end distance, or piled at the
    search's end, it is too close (rule 6), also when ``m`` has no distance; otherwise a frame without a
    distance stays without one (the guard never turns "no measurement" into a distance: on the leafy suite
    that let a +9 % reading out). Never farther than ``m``. Off with ``thin_guard_m2`` 0, on a frame already
    too close, and without the left-right check.
    """
    cfg = s.config
    if not (cfg.thin_guard_m2 > 0 and not m.too_close and result.lr_consistent is not None):
        return m
    x0, y0, x1, y1 = s.roi
    disp = result.measured[y0:y1, x0:x1]
    # The guard can only act through an object whose front is beyond ``need`` (nearer than m by more than
    # THIN_GUARD_NEARER_PX matched px, or within the too-close factor when m has no distance): fewer consistent
    # pixels there than an object needs, and nothing can change (most frames).
    lim_d = s.fb / (WEAK_TOO_CLOSE_FACTOR * s.search_end_m)
    need = (m.disparity_px + THIN_GUARD_NEARER_PX * s.px if m.valid
            else min(lim_d, s.d_max - CLUSTER_MARGIN_PX * s.px))
    with np.errstate(invalid="ignore"):
        ok = (disp >= s.d_floor) & result.lr_consistent[y0:y1, x0:x1]
        if np.count_nonzero(ok & (disp >= need)) < cfg.min_valid_px * s.px * s.px:
            return m
    found = _guard_object(s, disp, ok)
    if found is None:
        return m
    g, z, area_m2 = found
    if m.valid and (z >= m.distance_m * (1.0 - THIN_GUARD_NEARER_REL) or g.d <= need):
        return m
    if result.confidence is not None:
        with np.errstate(invalid="ignore"):
            member = ok & (disp >= g.lower) & (disp <= g.front + CLUSTER_MARGIN_PX * s.px)
        conf = result.confidence[y0:y1, x0:x1]
        if share_of(conf[member] >= cfg.min_confidence) >= THIN_GUARD_MAX_CONFIDENT_SHARE:
            return m       # the confident pixels saw this object: only the weighting differs
    lim = s.search_end_m
    if g.front >= s.d_max - CLUSTER_MARGIN_PX * s.px or z < WEAK_TOO_CLOSE_FACTOR * lim:
        return Measurement(None, n_px=m.n_px, valid_fraction=m.valid_fraction, too_close=True, guarded=True,
                           reason=f"thin guard: {area_m2 * 1e4:.1f} cm^2 of left-right-consistent matches read "
                                  f"{z:.3f} m, within {WEAK_TOO_CLOSE_FACTOR:g} x the search's end "
                                  f"{lim:.3f} m or at the search's end: too close",
                           reason_code=Reason.THIN_GUARD_TOO_CLOSE)
    if not m.valid:      # the guard makes a reading nearer or too close; it never turns "none" into a distance
        return m
    quality = int(min(100, max(2, round(100.0 * share_of(ok)))))
    g_m = replace(reading(s, g, shift(g.bbox, x0, y0), quality, m.valid_fraction), guarded=True)
    why = imprecise(s, g_m)
    if why is not None:      # nearer than m, but not precise: neither is sent
        return replace(g_m, distance_m=None, sigma_m=None, reason=f"thin guard: a nearer object: {why}",
                       reason_code=Reason.THIN_GUARD_SIGMA)
    return g_m


def _guard_object(s: Setup, disp: np.ndarray, ok: np.ndarray) -> tuple[NearestObject, float, float] | None:
    """The nearest object of the ``ok`` pixels (each weighing 1) whose band covers ``thin_guard_m2``, its distance
    (m) and visible area (m^2); None if there is none. A smaller one in front (stray consistent matches on sky or
    background at a false disparity, on the leafy sweep) is passed over, not taken as the answer, up to
    :data:`THIN_GUARD_MAX_SKIPPED` of them."""
    cand = ok
    for _ in range(THIN_GUARD_MAX_SKIPPED + 1):
        g = find(s, disp, None, cand, s.px)
        if g is None:
            return None
        z = s.fb / g.d
        area_m2 = g.n * (z / s.calibration.focal_px) ** 2
        if area_m2 >= s.config.thin_guard_m2:
            return g, z, area_m2
        with np.errstate(invalid="ignore"):
            cand = cand & (disp < g.lower)
    return None
