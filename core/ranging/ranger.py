"""The ranging stage: one explicit, ordered list of stages from a disparity result to one frame's reading.

:data:`READING` finds the confident reading; the first stage that decides the frame
(too close, no measurement) ends it. :data:`GUARDS` then act on whatever was
decided, and may only make it nearer or too close, never farther. :data:`CHECKS` last:
a too-close outcome whose evidence is sensor noise is no measurement. The rules each
stage applies, and the measurements behind their thresholds, are on docs/ranging.md.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging.fine import fine_pass
from uav_depth.core.ranging.floors import quality_floor, sigma_ceiling
from uav_depth.core.ranging.frame import RangingFrame
from uav_depth.core.ranging.measurement import Measurement
from uav_depth.core.ranging.nearest import usable
from uav_depth.core.ranging.reading import nearest_object, read
from uav_depth.core.ranging.setup import Setup
from uav_depth.core.ranging.thin_guard import thin_guard
from uav_depth.core.ranging.too_close import at_search_end, near_check, near_end_band, noise_floor

#: A reading stage decides the frame (returns its measurement) or leaves it to the next stage (None).
ReadingStage = Callable[[Setup, RangingFrame], "Measurement | None"]
#: A guard maps the decided measurement to one never farther.
Guard = Callable[[Setup, Measurement, DisparityResult], Measurement]

#: The confident reading, in order (the too-close rules numbered as on docs/ranging.md, *Too close*).
READING: tuple[tuple[str, ReadingStage], ...] = (
    ("near check", near_check),            # too close: the near pass's evidence (rules 1, 3, 4)
    ("nearest object", nearest_object),    # the nearest significant object; none: no measurement
    ("search end", at_search_end),         # too close: the object piles at the search's end (rule 2)
    ("quality floor", quality_floor),      # no measurement under min_quality, or too close (rule 7)
    ("reading", read),                     # Z = f*B/d, sigma_Z
    ("fine pass", fine_pass),              # re-measured at full resolution, never farther on a weak match
    ("near end band", near_end_band),      # too close: in the search's last 5 % (rule 8)
    ("sigma ceiling", sigma_ceiling),      # no measurement less precise than max_sigma_m at the object's body
)
#: Then, on whatever was decided: may make it nearer or too close (rule 6), never farther.
GUARDS: tuple[tuple[str, Guard], ...] = (
    ("thin guard", thin_guard),
)
#: Last, on a too-close outcome of any rule: its evidence must survive the sensor noise, or it is no measurement.
CHECKS: tuple[tuple[str, Guard], ...] = (
    ("noise floor", noise_floor),
)


class Ranger(Setup):
    """The ranging stage for one calibration, ROI and parameter set (rebuilt on a parameter swap).

    ``calibration`` is the *rectified* calibration; ``roi`` (x0, y0, x1, y1) px. What
    construction derives once is :class:`.setup.Setup`'s.
    """

    def measure(self, result: DisparityResult) -> Measurement:
        """The nearest significant object's distance in the ROI of one disparity result."""
        x0, y0, x1, y1 = self.roi
        disp = result.measured[y0:y1, x0:x1]
        conf = None if result.confidence is None else result.confidence[y0:y1, x0:x1]
        ok = usable(self, disp, conf)
        n_valid = np.count_nonzero(ok)
        frame = RangingFrame(result, disp, conf, ok, n_valid, n_valid / disp.size)
        m = None
        for _, stage in READING:
            m = stage(self, frame)
            if m is not None:
                break
        else:
            m = frame.reading
        assert m is not None
        for _, guard in (*GUARDS, *CHECKS):
            m = guard(self, m, result)
        return m
