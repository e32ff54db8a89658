"""What the service reports about itself: liveness, the status line, sd_notify.

:class:`Health` reads the shared :class:`~uav_depth.daemon.state.ServiceState` and the
threads it watches; the main loop calls :meth:`Health.tick` every 100 ms: WATCHDOG=1
while :meth:`Health.healthy` (every thread alive, nothing stuck), and the status line
to the log and to systemd's STATUS every ``status_interval_s``.
"""

from __future__ import annotations

import logging
import time
from typing import Callable, Protocol

from uav_depth.daemon.config import ServiceConfig
from uav_depth.daemon.link.clock import SendClock
from uav_depth.daemon.notify import Notifier
from uav_depth.daemon.estimate import Estimate
from uav_depth.daemon.state import ServiceState, Stats

log = logging.getLogger("uav_depth.service")


class Alive(Protocol):
    """A part that runs a thread of the service."""

    @property
    def alive(self) -> bool: ...


def status_line(stats: Stats, estimate: Estimate | None, clock: SendClock | None, params_hash: str | None,
                camera_ok: bool, now: float | None = None, notes: tuple[str, ...] = ()) -> str:
    """One line for the operator: fps, distance (or why none), timings, what reached the autopilot (or that none
    is heard: :meth:`SendClock.delivery`), the parameters; ``notes``: what else the operator must know (a dead
    thread, stereo pairs dropped)."""
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
            f"params {params_hash or '-'}{'' if camera_ok else ', CAMERA LOST'}"
            + "".join(f", {note}" for note in notes))


class Health:
    """Liveness and reporting of one service, run by the main loop (:meth:`tick` every 100 ms).

    ``state``: the shared state (its stall timers are read here); ``status``: builds the
    current status line. :meth:`watch` registers each thread the service starts: every
    thread's death is a health failure, so WATCHDOG=1 stops and systemd restarts the daemon.
    """

    def __init__(self, config: ServiceConfig, notifier: Notifier, state: ServiceState, status: Callable[[], str]):
        self.config = config
        self.notifier = notifier
        self.state = state
        self.status = status
        self.watched: dict[str, Alive] = {}
        self.dead: tuple[str, ...] = ()          # the threads found dead, once found (main thread)
        self._next_status = 0.0
        self._next_dog = 0.0

    def watch(self, name: str, part: Alive) -> None:
        """Watch the thread of ``part``: ``part.alive`` False while the service runs is a death (the watchdog
        stops). Each part says what alive means for it (a finished source, a frame log that stopped on purpose)."""
        self.watched[name] = part

    def healthy(self, now: float | None = None) -> bool:
        """True while every watched thread lives and neither the stereo stage nor the source is stuck.

        Stuck: one frame in the stereo stage, or one read/open of the source, for longer
        than ``service.stall_timeout_s``. Then WATCHDOG=1 stops and systemd restarts us.
        A thread found dead (the link's I/O thread included: ``link.alive``) is said once, in one error line.
        """
        now = time.monotonic() if now is None else now
        dead = tuple(name for name, part in self.watched.items() if not part.alive)
        if dead and dead != self.dead:
            log.error("thread%s %s died: WATCHDOG=1 stops, so systemd restarts the daemon", "s" * (len(dead) > 1),
                      ", ".join(dead))
        self.dead = dead
        limit = self.config.stall_timeout_s
        busy, reading = self.state.busy_since, self.state.source_since
        return (bool(self.watched) and not dead
                and (busy is None or now - busy < limit)
                and (reading is None or now - reading < limit))

    def ready(self) -> None:
        """Start-up is done: log and send READY=1 with the first status line."""
        status = self.status()
        log.info("ready: %s", status)
        self.notifier.ready(status)
        self._next_status = time.monotonic() + self.config.status_interval_s

    def tick(self, now: float | None = None) -> None:
        """Called by the main loop: WATCHDOG=1 while healthy, the status line when due."""
        now = time.monotonic() if now is None else now
        wd = self.notifier.watchdog_s
        healthy = self.healthy(now)
        if wd and now >= self._next_dog and healthy:
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
        busy, reading = self.state.busy_since, self.state.source_since
        if name == "stereo" and busy:
            return f" (busy for {now - busy:.1f} s on a frame)"
        if name == "capture" and reading:
            return f" (stuck for {now - reading:.1f} s in the source)"
        return ""
