"""What the stereo thread hands the send clock: one accepted measurement of one frame, with its age's origin."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from uav_depth.core.ranging import Measurement, RangeLimits


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
