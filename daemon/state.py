"""What the service's threads share: one object, each field written by one thread.

Every other thread only reads. A write is one attribute assignment (or an event set),
which Python makes atomic, so no field needs a lock; a reader may see a field one
write behind, never half of one. Who writes what:

==================  ==========  ==============================================================
field               writer      meaning
==================  ==========  ==============================================================
``estimate``        stereo      the newest accepted estimate: what the send clock sends
``last_estimate``   stereo      the newest frame's result, accepted or not (status, logs)
``frames_done``     stereo      frames the stereo stage finished (processed, skipped or failed)
``first_frame``     stereo      set once the first frame was processed (start-up is done)
``startup_error``   stereo      why the first frames cannot be processed (start-up fails on it)
``busy_since``      stereo      when the stereo stage took its current frame (None: idle)
``stats``           stereo      rolling per-stage timings and counters
``camera_ok``       capture     frames are arriving (False from a loss until the next frame)
``camera_losses``   capture     losses so far: the stereo thread resets its outlier gate when
                                this moves, so the gate has one owner
``ended``           capture     why a finite source ended (None while it delivers)
``source_since``    capture     when the capture thread entered the source (None: outside it)
``stopping``        main        set once shutdown began: nothing is sent from then on
==================  ==========  ==============================================================

The current stereo stage is the one thing shared elsewhere:
:attr:`~uav_depth.daemon.stage.StageHolder.stage`, written by the parameter watcher's
thread (and by the main thread once, at start-up, before the watcher runs).
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Iterator, Mapping

from uav_depth.daemon.estimate import Estimate


@dataclass
class Stats:
    """Rolling per-stage timings (ms) and counters for the status line and the benchmark."""

    window: int = 200
    stages: dict[str, collections.deque] = field(default_factory=dict)
    frames: int = 0
    frame_times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=200))

    def add(self, t_done: float, timings: Mapping[str, float]) -> None:
        self.frames += 1
        self.frame_times.append(t_done)
        for k, v in timings.items():
            self.stages.setdefault(k, collections.deque(maxlen=self.window)).append(v)

    def fps(self, now: float, span_s: float = 5.0) -> float:
        recent = [t for t in list(self.frame_times) if now - t <= span_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)

    def median(self, stage: str) -> float:
        vals = sorted(self.stages.get(stage, ()))
        return vals[len(vals) // 2] if vals else math.nan


class ServiceState:
    """The state the service's threads share (see the module docstring for each field's writer)."""

    def __init__(self) -> None:
        self.estimate: Estimate | None = None
        self.last_estimate: Estimate | None = None
        self.frames_done = 0
        self.first_frame = threading.Event()
        self.startup_error: Exception | None = None
        self.busy_since: float | None = None
        self.stats = Stats()
        self.camera_ok = False
        self.camera_losses = 0
        self.ended: str | None = None
        self.source_since: float | None = None
        self.stopping = threading.Event()

    def current_estimate(self) -> Estimate | None:
        """What the send clock reads: the newest accepted estimate."""
        return self.estimate

    @contextlib.contextmanager
    def in_source(self) -> Iterator[None]:
        """The capture thread is inside the source (a read or an open), for the stall check."""
        self.source_since = time.monotonic()
        try:
            yield
        finally:
            self.source_since = None
