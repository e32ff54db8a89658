"""What the service reports about itself: rolling figures, liveness, the status line, sd_notify.

:class:`Health` is written to by the service's threads (one attribute at a time:
the frame and source timers, the stats) and read by the main loop, which calls
:meth:`Health.tick` every 100 ms: WATCHDOG=1 while :meth:`Health.healthy`, and
the status line to the log and to systemd's STATUS every ``status_interval_s``.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping

from uav_depth.daemon.config import ServiceConfig
from uav_depth.daemon.link.clock import SendClock
from uav_depth.daemon.notify import Notifier
from uav_depth.daemon.ranging import Estimate

log = logging.getLogger("uav_depth.service")


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
        recent = [t for t in self.frame_times if now - t <= span_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)

    def median(self, stage: str) -> float:
        vals = sorted(self.stages.get(stage, ()))
        return vals[len(vals) // 2] if vals else math.nan


def status_line(stats: Stats, estimate: Estimate | None, clock: SendClock | None, params_hash: str | None,
                camera_ok: bool, now: float | None = None) -> str:
    """One line for the operator: fps, distance (or why none), timings, what reached the autopilot (or that none
    is heard: :meth:`SendClock.delivery`), the parameters."""
    now = time.monotonic() if now is None else now
    if estimate is None:
        dist = "no frame yet"
    elif estimate.measurement.valid:
        truth = f", truth {estimate.truth_m:.3f} m" if estimate.truth_m is not None else ""
        dist = f"distance {estimate.measurement.distance_m:.3f} m (q {estimate.measurement.quality}{truth})"
    else:
        dist = f"no measurement ({estimate.measurement.reason})"
    sent = clock.delivery(now) if clock else "nothing sent"
    return (f"{stats.fps(now):.1f} fps, {dist}, disparity {stats.median('disparity'):.0f} ms, "
            f"latency {stats.median('latency'):.0f} ms, {sent}, "
            f"params {params_hash or '-'}{'' if camera_ok else ', CAMERA LOST'}")


class Health:
    """Liveness and reporting of one service. ``status``: builds the current status line."""

    def __init__(self, config: ServiceConfig, notifier: Notifier, status: Callable[[], str]):
        self.config = config
        self.notifier = notifier
        self.status = status
        self.stats = Stats()
        self.busy_since: float | None = None     # when the stereo stage took its current frame
        self.source_since: float | None = None   # when the capture thread entered the source (read/open)
        self._next_status = 0.0
        self._next_dog = 0.0

    @contextlib.contextmanager
    def in_source(self) -> Iterator[None]:
        """Mark the capture thread as inside the source (a read or open) for the stall check."""
        self.source_since = time.monotonic()
        try:
            yield
        finally:
            self.source_since = None

    def healthy(self, clock: SendClock | None, threads: Mapping[str, threading.Thread],
                now: float | None = None) -> bool:
        """True while every loop is alive and neither the stereo stage nor the source is stuck.

        Stuck: one frame in the stereo stage, or one read/open of the source, for longer
        than ``service.stall_timeout_s``. Then WATCHDOG=1 stops and systemd restarts us.
        The send clock's link counts as a loop: its I/O thread (``link.alive``).
        """
        now = time.monotonic() if now is None else now
        limit = self.config.stall_timeout_s
        busy, reading = self.busy_since, self.source_since
        return (clock is not None and clock.alive and clock.link.alive
                and all(t.is_alive() for t in threads.values())
                and (busy is None or now - busy < limit)
                and (reading is None or now - reading < limit))

    def ready(self) -> None:
        """Start-up is done: log and send READY=1 with the first status line."""
        status = self.status()
        log.info("ready: %s", status)
        self.notifier.ready(status)
        self._next_status = time.monotonic() + self.config.status_interval_s

    def tick(self, healthy: Callable[[float], bool], now: float | None = None) -> None:
        """Called by the main loop: WATCHDOG=1 while healthy, the status line when due."""
        now = time.monotonic() if now is None else now
        wd = self.notifier.watchdog_s
        if wd and now >= self._next_dog and healthy(now):
            self.notifier.watchdog()
            self._next_dog = now + wd / 3.0
        if now >= self._next_status:
            line = self.status()
            log.info("status: %s", line)
            self.notifier.status(line)
            self._next_status = now + self.config.status_interval_s

    def abandoned_detail(self, name: str, now: float | None = None) -> str:
        """Why thread ``name`` may be stuck, for the shutdown report ('' when unknown)."""
        now = time.monotonic() if now is None else now
        busy, reading = self.busy_since, self.source_since
        if name == "stereo" and busy:
            return f" (busy for {now - busy:.1f} s on a frame)"
        if name == "capture" and reading:
            return f" (stuck for {now - reading:.1f} s in the source)"
        return ""
