"""What every frame source delivers: :class:`Frame`, and the :class:`FrameSource` contract (the runtime's cameras
and replay implement it, and so does the simulator's synthetic source)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import SourceError


#: A device timestamp older than this (behind the host's receive time) is not believed.
MAX_DEVICE_LAG_S = 2.0


def device_capture_time(stamps: "list[float | None]", now: float, max_lag_s: float = MAX_DEVICE_LAG_S) -> float:
    """The capture time of a pair from its devices' own timestamps (monotonic s), else ``now``.

    ``stamps``: each eye's device timestamp on the host's CLOCK_MONOTONIC (depthai's
    ``getTimestamp()``, V4L2 buffer timestamps), None where the device gave none. The
    earliest plausible one wins (ages are then never understated); a stamp in the
    future or more than ``max_lag_s`` behind ``now`` is on another clock and ignored.
    ``now``: the host's time when the pair arrived, the fallback.
    """
    good = [t for t in stamps if t is not None and now - max_lag_s <= t <= now]
    return min(good) if good else now


class EndOfStream(SourceError):
    """A finite source (a replay without loop) has delivered its last frame."""


@dataclass(frozen=True)
class Frame:
    """One stereo pair as captured.

    ``left``/``right``: uint8 (H, W) grey or (H, W, 3) BGR, raw or rectified as the
    source's calibration says. ``t_capture``: ``time.monotonic()`` seconds when the
    pair was captured; every age (``ranging.max_age_ms``) is measured from it.
    ``truth_m``: the true distance to the nearest branch in the truth ROI when the
    source knows it (synthetic scenes, replayed synthetic logs), else None.
    ``reference``: (H, W) float32 reference disparity of the left image in px, NaN
    unknown (synthetic: exact; OAK: the device's own), with ``reference_source``
    saying where it came from.
    """

    left: np.ndarray
    right: np.ndarray
    index: int
    t_capture: float = field(default_factory=time.monotonic)
    truth_m: float | None = None
    reference: np.ndarray | None = None
    reference_source: Mapping[str, Any] | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)


class FrameSource(Protocol):
    """A camera, a log or a simulation.

    ``open()`` raises :class:`SourceError` quickly (well under a second) when the
    device is missing, saying what is missing. ``read(timeout_s)`` returns the next
    frame, None when none came within ``timeout_s``, raises :class:`SourceError`
    when the device is lost (the service closes, then reopens with back-off) and
    :class:`EndOfStream` when a finite source is done. ``calibration`` is the
    source's own calibration (None when it carries none), valid after ``open()``.
    Sources are used from one thread at a time.
    """

    kind: str
    calibration: Calibration | None

    def open(self) -> None: ...

    def read(self, timeout_s: float) -> Frame | None: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...
