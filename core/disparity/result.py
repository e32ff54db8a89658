"""What one disparity run returns, and the stopwatch that times its stages."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np


@dataclass(frozen=True)
class DisparityResult:
    """Output of one pipeline run; every map is (H, W) at the input's resolution.

    ``disparity``: float32 px, NaN where invalid: the WLS output when the refine
    stage ran, else the same values as ``measured``. ``measured``: float32 px of the
    left matcher alone, after its uniqueness, left-right (disp12_max_diff) and
    speckle checks: the pixels that were really matched, never filled in. This is
    what ranging and the flown objective use. ``confidence``: float32 in 0..1, the
    left-right confidence of each measured pixel (OpenCV's WLS definition, see
    :mod:`.confidence`), 0 outside the region, or None when the right matcher is
    off (``wls.enabled: false``). ``warning``: why the maps are empty when the
    parameters cannot be computed. ``timings_ms``: wall time of each stage of this
    run (prepare, match_left, match_right, confidence, wls, assemble, near), ms.
    ``near``: the near check (:mod:`.near`) when the pipeline was built with
    ``near=True``, else None (its confidence is ``near.confidence()``, computed when asked for);
    ``near_consistent``: the near pass's left-right check alone (layout of ``lr_consistent``) to filter
    ``near.disparity`` with. ``fine``: when the
    flight pipeline has a fine pass (``compute.fine_disparities``), ``fine(box, d0)`` re-matches
    ``box`` (x0, y0, x1, y1 input px) of this frame at full resolution over disparities from ``d0``
    (:class:`.fine.FineMatch`, or None when the box cannot be matched); else None.
    ``lr_consistent``: (H, W) bool, the measured pixels whose match passes the left-right check
    (or cannot be checked) whatever their depth-edge weight (:func:`.confidence.confidence_maps`),
    or None without the right matcher.
    """

    disparity: np.ndarray
    measured: np.ndarray
    confidence: np.ndarray | None
    warning: str | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)
    near: Any = None
    near_consistent: np.ndarray | None = None
    fine: Callable[[tuple[int, int, int, int], int], Any] | None = None
    lr_consistent: np.ndarray | None = None


class Laps:
    """Stage stopwatch: ``lap(name)`` books the time since the previous lap under ``name``."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = self.ms.get(name, 0.0) + (now - self._t) * 1000.0
        self._t = now
