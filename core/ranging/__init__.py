"""Branch ranging: from a disparity result to the distance of the nearest significant object in the ROI.

Only pixels the matcher really measured are used (``DisparityResult.measured``,
not WLS fill-in), and only where the left-right confidence is at least
``min_confidence``. :class:`Ranger` runs one declared list of stages
(:mod:`.ranger`: :data:`READING`, then :data:`GUARDS`, then :data:`CHECKS`), one module per rule
(docs/ranging.md says why each rule and threshold is what it is):

* :mod:`.config` and :mod:`.limits`: the ``ranging:`` section, the range limits the wire states;
* :mod:`.setup`: what one calibration, ROI and parameter set fix (the search in input px, the floors);
* :mod:`.nearest`: the nearest significant object and its reading, Z = f*B/d,
  sigma_Z = Z^2/(f*B) * sigma_d, with :mod:`.slant` (a slanted object read at its near end);
* :mod:`.too_close`: too close by the near check, at the search's end, in its last band, and the
  noise floor every too-close outcome must pass;
* :mod:`.floors`: the quality floor (and rule 7) and the sigma ceiling (judged at the object's body);
* :mod:`.fine`: the fine pass (``compute.fine_disparities``): never farther than the coarse
  pass saw on a fine match that does not hold up;
* :mod:`.thin_guard`: matched pixels that pass the left-right check but not ``min_confidence``
  may make the reading nearer, or too close, never farther;
* :mod:`.gate`: :class:`OutlierGate` lets a nearer reading through at once and holds a jump
  away until ``confirm_frames`` frames agree.

Each outcome without a distance carries a :class:`Reason` code (``Measurement.reason_code``)
with its text beside it (``Measurement.reason``).
"""

from __future__ import annotations

from uav_depth.core.ranging.config import THIN_GUARD_M2, RangingConfig
from uav_depth.core.ranging.gate import OutlierGate
from uav_depth.core.ranging.limits import (NEAR_END_BAND, PIXEL_LOCKING_SIGMA_PX, WEAK_TOO_CLOSE_FACTOR,
                                           WIRE_SIGMA_MAX_M, RangeLimits, default_roi, resolve_roi)
from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.ranger import CHECKS, GUARDS, READING, Ranger

__all__ = ["CHECKS", "GUARDS", "NEAR_END_BAND", "OutlierGate", "PIXEL_LOCKING_SIGMA_PX", "READING", "RangeLimits",
           "Ranger", "RangingConfig", "Reason", "Measurement", "THIN_GUARD_M2", "WEAK_TOO_CLOSE_FACTOR",
           "WIRE_SIGMA_MAX_M", "default_roi", "resolve_roi"]
