"""Ground-truth distance for ranging: the nearest *significant* object in the ranging region.

A significant object is one the pruning tool or the airframe would hit and be
hurt by, defined in metres so the rule holds at any range and any
``compute.scale``:

- it is at least :data:`SIGNIFICANT_WIDTH_M` (3 mm) thick: a twig of 3-10 mm
  deflects the saw and snags a propeller; a pine needle (about 1 mm) is cut
  through by the saw and bent aside by the airframe, so a needle alone is *not*
  significant (the truth disparity still holds it, exactly);
- it shows at least :data:`SIGNIFICANT_AREA_M2` (2 cm^2) of its surface inside
  the region (visible area: sum over its pixels of (Z / f)^2), so a twig's tip
  poking 5 mm into the region does not define the distance.

The background plane (the canopy behind) is significant; the sky is not an object.
The distance is that of the object's nearest visible surface, along the optical axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# One definition, shared with the daemon's ranging (ranging.min_object_m2 defaults to the area).
from uav_depth.core.significant import SIGNIFICANT_AREA_M2, SIGNIFICANT_WIDTH_M


@dataclass(frozen=True)
class Truth:
    """Ground truth of one frame in one region; distances in m along the optical axis, NaN if none.

    ``significant_m``: the nearest significant object (what ranging must not report
    farther than); ``nearest_any_m``: the nearest surface of anything, needles included;
    ``object_index``: which object defined ``significant_m`` (-1 none; 0 background
    plane, i + 1 the scene's cylinder i); ``area_m2``: its visible area in the region.
    """

    significant_m: float
    nearest_any_m: float
    object_index: int
    area_m2: float


def is_significant(thickness_m: float, visible_area_m2: float) -> bool:
    """The rule, in one place: thick enough to hurt and large enough in the region."""
    return thickness_m >= SIGNIFICANT_WIDTH_M and visible_area_m2 >= SIGNIFICANT_AREA_M2


def nearest_significant(depth: np.ndarray, objects: np.ndarray, thickness_m: np.ndarray, focal_px: float,
                        roi: tuple[int, int, int, int] | None = None) -> Truth:
    """The truth in ``roi`` (x0, y0, x1, y1) of a left view.

    ``depth`` (H, W) m; ``objects`` (H, W) int, -1 where nothing (sky), else the
    object's index; ``thickness_m`` (n_objects,) m per object index.
    """
    if roi is not None:
        x0, y0, x1, y1 = roi
        depth, objects = depth[y0:y1, x0:x1], objects[y0:y1, x0:x1]
    hit = objects >= 0
    if not hit.any():
        return Truth(math.nan, math.nan, -1, 0.0)
    ids, z = objects[hit].astype(np.int64), depth[hit].astype(np.float64)
    n = len(thickness_m)
    area = np.bincount(ids, weights=(z / focal_px) ** 2, minlength=n)
    near = np.full(n, np.inf)
    np.minimum.at(near, ids, z)
    best, best_i = math.inf, -1
    for i in np.flatnonzero(np.isfinite(near)):
        if is_significant(float(thickness_m[i]), float(area[i])) and near[i] < best:
            best, best_i = float(near[i]), int(i)
    return Truth(best if best_i >= 0 else math.nan, float(z.min()), best_i,
                 float(area[best_i]) if best_i >= 0 else 0.0)
