"""The nearest significant object of a disparity map, and its reading (Z = f*B/d).

1. ``front``: the nearest disparity at which the pixels at least as near make at least
   ``min_valid_px`` matched pixels and ``min_object_m2`` of visible area
   (:mod:`uav_depth.core.significant`), so that stray near pixels cannot pull it forward
   at any range or ``compute.scale``;
2. the object: every pixel between ``front`` and the disparity of a surface
   ``cluster_depth_m`` behind it, widened by one matched pixel for matching noise;
3. its disparity: the confidence-weighted quantile that leaves ``surface_quantile`` of the
   object nearer, read again where a slanted object is nearest (:mod:`.slant`); its spread
   sigma_d: 1.4826 x the weighted median absolute deviation, at least the pixel-locking floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uav_depth.core.ranging.limits import PIXEL_LOCKING_SIGMA_PX
from uav_depth.core.ranging.measurement import Measurement
from uav_depth.core.ranging.setup import Setup
from uav_depth.core.ranging.slant import slanted_surface
from uav_depth.core.ranging.stats import weighted_median, weighted_quantiles

#: Disparity margin around the object's depth band, matched px: SGBM's typical matching noise.
CLUSTER_MARGIN_PX = 1.0


@dataclass(frozen=True)
class NearestObject:
    """The nearest significant object of one map: ``front`` disparity, reported disparity ``d`` and its
    spread ``sigma_d`` (input px), pixel count ``n`` (input px), mean confidence, the band's lower
    disparity ``lower``, ``bbox`` (x0, y0, x1, y1) in the map's own coordinates, and the band's median
    disparity ``median`` (input px), the object's body."""

    front: float
    d: float
    sigma_d: float
    n: int
    mean_conf: float
    lower: float
    bbox: tuple[int, int, int, int]
    median: float


def shift(box: tuple[int, int, int, int], dx: int, dy: int) -> tuple[int, int, int, int]:
    return box[0] + dx, box[1] + dy, box[2] + dx, box[3] + dy


def usable(s: Setup, disp: np.ndarray, conf: np.ndarray | None) -> np.ndarray:
    """Measured pixels above the far floor and (with a confidence map) confident enough."""
    with np.errstate(invalid="ignore"):     # NaN compares False: unmatched pixels drop out
        ok = disp >= s.d_floor
        if conf is not None:
            ok &= conf >= s.config.min_confidence
    return ok


def front_disparity(s: Setup, vals: np.ndarray, px: float, count_px: float) -> float | None:
    """The nearest disparity (px) at which the pixels at least as near form a significant object:
    at least ``min_valid_px`` matched pixels (of ``count_px`` input px across; disparities matched at
    ``px`` input px per matched px) and ``min_object_m2`` of visible area; None if none."""
    if vals.size == 0:
        return None
    cfg = s.config
    # Disparities in 1/16 matched px (SGBM's own resolution), counted from the nearest down.
    q = np.rint(vals * (16.0 / px)).astype(np.int64)
    counts = np.bincount(q)
    levels = np.arange(counts.size) * (px / 16.0)
    with np.errstate(divide="ignore"):
        px_area = np.where(levels > 0, (s.calibration.baseline_m / np.maximum(levels, 1e-9)) ** 2, 0.0)
    n_near = np.cumsum(counts[::-1])[::-1] / (count_px * count_px)   # matched pixels at or nearer
    a_near = np.cumsum((counts * px_area)[::-1])[::-1]                # m^2 at or nearer
    hit = np.flatnonzero((n_near >= cfg.min_valid_px) & (a_near >= cfg.min_object_m2))
    if hit.size == 0:
        return None
    return float(vals[q >= hit[-1]].min())


def find(s: Setup, disp: np.ndarray, conf: np.ndarray | None, ok: np.ndarray, px: float,
         count_px: float | None = None, margin_px: float | None = None,
         slant_cap: float | None = None) -> NearestObject | None:
    """The nearest significant object among the ``ok`` pixels of a map matched at ``px`` input px per
    matched px (rules 1-3 of the module docstring); None if there is none. ``count_px``: the matched
    pixel ``min_valid_px`` counts, input px across (default ``px``; the fine pass counts the coarse
    pass's, so that its object covers the same image area); ``margin_px``: the band's widening for
    matching noise, input px (default one matched pixel)."""
    cfg = s.config
    vals = disp[ok]
    front = front_disparity(s, vals, px, px if count_px is None else count_px)
    if front is None:
        return None
    margin = CLUSTER_MARGIN_PX * px if margin_px is None else margin_px
    lower = s.fb / (s.fb / front + cfg.cluster_depth_m) - margin
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
    d, med = weighted_quantiles(v, w, 1.0 - cfg.surface_quantile, 0.5)
    sigma_d = max(1.4826 * weighted_median(np.abs(v - med), w), PIXEL_LOCKING_SIGMA_PX * px)
    d = slanted_surface(cfg, inbox, dbox, wbox, front, d, front if slant_cap is None else min(front, slant_cap),
                        px if count_px is None else count_px)
    return NearestObject(front, d, sigma_d, int(v.size), float(w.mean()) if w is not None else 1.0, lower, bbox,
                         med)


def reading(s: Setup, obj: NearestObject, bbox: tuple[int, int, int, int], quality: int, valid_fraction: float,
            refined: bool = False) -> Measurement:
    """The object's distance Z = f*B/d and its sigma_Z = Z^2/(f*B) * sigma_d."""
    z = s.fb / obj.d
    return Measurement(distance_m=z, sigma_m=z * z / s.fb * obj.sigma_d, quality=quality, bbox=bbox,
                       disparity_px=obj.d, sigma_px=obj.sigma_d, n_px=obj.n, valid_fraction=valid_fraction,
                       refined=refined, body_px=obj.median)
