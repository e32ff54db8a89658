"""What one disparity run returns (typed, one dataclass per stage's output), and the stopwatch that times its
stages."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol

import numpy as np

#: (x0, y0, x1, y1) px of the input image, x1/y1 exclusive.
Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class NearCheck:
    """The near check of one frame (:mod:`.near`): is something nearer than the main search can match?

    ``disparity``: (H, W) float32 disparity px (input resolution) the near pass
    measured, NaN where it matched nothing; ranging looks at the pixels beyond
    ``max_disparity_px``, the main search's largest disparity, input px.
    """

    disparity: np.ndarray
    max_disparity_px: float
    #: ``textured()``: (H, W) bool, both views textured here at the near pass's scale (:func:`.near.textured`),
    #: False outside the near pass's region; computed when first asked for (ranging asks only for a frame
    #: that is otherwise blank). None when not available.
    textured: Callable[[], np.ndarray] | None = None
    #: ``confidence()``: (H, W) float32 0..1, the near pass's confidence (layout of
    #: ``DisparityResult.confidence``), computed when first asked for: ranging asks only when the main pass
    #: has matched too little of the region (rule 4), and its depth-edge weights are most of the check's
    #: cost. None without the near pass's right matcher.
    confidence: Callable[[], np.ndarray] | None = None
    #: (H, W) bool: the near pass's left-right check alone (layout of ``DisparityResult.lr_consistent``), to
    #: filter ``disparity`` with; None without its right matcher.
    consistent: np.ndarray | None = None
    #: ``left_textured()``: (H, W) bool, the left view textured here at the near pass's scale
    #: (:func:`.near.left_textured`), False outside the near pass's region; computed when first asked for
    #: (ranging asks only for a frame it would report too close). None when not available.
    left_textured: Callable[[], np.ndarray] | None = None


@dataclass(frozen=True)
class FineMatch:
    """The fine pass over one box of the input image (:mod:`.fine`).

    ``box``: (x0, y0, x1, y1) input px; ``measured``: (y1 - y0, x1 - x0) float32
    disparity px (input resolution, the shift added back), NaN where nothing was
    matched; ``confidence``: the same shape, 0..1 left-right confidence, or None
    without the right matcher (``wls.enabled: false``); ``d_lo``/``d_hi``: the smallest and largest
    disparity searched, input px.
    """

    box: Box
    measured: np.ndarray
    confidence: np.ndarray | None
    d_lo: float
    d_hi: float


class FineRematch(Protocol):
    """The fine pass offered to ranging for one frame: ``match(box, d0)`` re-matches ``box`` (input px) at full
    resolution over disparities from ``d0`` (input px); None when the box cannot be matched."""

    def match(self, box: Box, d0: int) -> FineMatch | None: ...


@dataclass(frozen=True)
class DisparityResult:
    """Output of one pipeline run; every map is (H, W) at the input's resolution.

    ``disparity``: float32 px, NaN where invalid: the WLS output when the pipeline's
    steps include WLS, else the same values as ``measured``. ``measured``: float32 px of the
    left matcher alone, after its uniqueness, left-right (disp12_max_diff) and
    speckle checks: the pixels that were really matched, never filled in. This is
    what ranging and the flown objective use. ``confidence``: float32 in 0..1, the
    left-right confidence of each measured pixel (OpenCV's WLS definition, see
    :mod:`.confidence`), 0 outside the region, or None when the right matcher is
    off (``wls.enabled: false``). ``warning``: why the maps are empty when the
    parameters cannot be computed. ``timings_ms``: wall time of each stage of this
    run (prepare, match_left, match_right, confidence, wls, assemble, near), ms.
    ``near``: the near check when the pipeline's steps include it, else None.
    ``fine``: the fine pass ranging may ask for, when the steps include it and the
    parameters have one (``compute.fine_disparities`` below full resolution), else None.
    ``lr_consistent``: (H, W) bool, the measured pixels whose match passes the left-right check
    (or cannot be checked) whatever their depth-edge weight (:func:`.confidence.confidence_maps`),
    or None without the right matcher.
    """

    disparity: np.ndarray
    measured: np.ndarray
    confidence: np.ndarray | None
    warning: str | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)
    near: NearCheck | None = None
    fine: FineRematch | None = None
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
