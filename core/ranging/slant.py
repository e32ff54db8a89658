"""The slanted-surface window: a branch seen obliquely is read at its near end, not across its whole band."""

from __future__ import annotations

import numpy as np

from uav_depth.core.ranging.config import RangingConfig
from uav_depth.core.ranging.stats import count_median, weighted_quantiles

#: A slanted object's surface is also read in a square window this many matched px a side around its front
#: pixels, where it is nearest (0 turns the rule off): wide enough to hold an object's min_valid_px at any
#: slant, narrow enough to sit at the near end of a branch crossing the region (docs/ranging.md, *Slanted
#: objects*).
FRONT_WINDOW_MATCHED_PX = 20


def slanted_surface(config: RangingConfig, mask: np.ndarray, disp: np.ndarray, weight: np.ndarray | None,
                    front: float, d: float, cap: float, count_px: float) -> float:
    """The object's reported disparity ``d``, read again where the object is nearest.

    The quantile over the whole band reads a branch seen obliquely (braking pitch, yaw)
    near its middle, farther than its near end: up to 7 % on the SITL scene at 7 degrees.
    So the same quantile is also taken over the object's pixels in a square window
    (:data:`FRONT_WINDOW_MATCHED_PX` matched px a side) centred on the median position
    of its front pixels (those at least as near as ``front``): on a slanted object they
    gather at its near end, on a level one they scatter along it and the window sits in
    its middle. The window's reading wins when it is nearer and the window holds at
    least ``config.min_valid_px`` matched pixels of the object. Never farther than ``d``, never
    nearer than ``cap`` (the front; for the fine pass the coarse pass's front if that is
    farther). ``mask``: the object's pixels in its box; ``disp`` and ``weight`` (None:
    each pixel weighs 1): the map and the weights over the same box.
    """
    if FRONT_WINDOW_MATCHED_PX <= 0:
        return d
    with np.errstate(invalid="ignore"):
        at_front = mask & (disp >= front)
    # The front pixels' median row and column from their counts per row and per column.
    per_row = np.count_nonzero(at_front, axis=1)
    if not per_row.any():
        return d
    half = FRONT_WINDOW_MATCHED_PX * count_px / 2.0
    cy, cx = count_median(per_row), count_median(np.count_nonzero(at_front, axis=0))
    # The window: the box's rows and columns within ``half`` of the centre (a slice of the box).
    r = np.flatnonzero(np.abs(np.arange(mask.shape[0]) - cy) <= half)
    c = np.flatnonzero(np.abs(np.arange(mask.shape[1]) - cx) <= half)
    if r.size == 0 or c.size == 0:
        return d
    win = (slice(int(r[0]), int(r[-1]) + 1), slice(int(c[0]), int(c[-1]) + 1))
    inside = mask[win]
    if np.count_nonzero(inside) < config.min_valid_px * count_px * count_px:
        return d
    v = disp[win][inside].astype(np.float64)
    w = weight[win][inside].astype(np.float64) if weight is not None else None
    (near_end,) = weighted_quantiles(v, w, 1.0 - config.surface_quantile)
    return min(max(near_end, d), max(d, cap))
