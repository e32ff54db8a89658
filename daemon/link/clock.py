"""The send clock: each new estimate on the wire as soon as it exists, HEARTBEAT at 1 Hz, STATUSTEXT on changes.

:class:`SendClock` evaluates the wire contract (:func:`~.contract.distance_report`) on
every new estimate (the stereo stage calls :meth:`SendClock.notify`) and at least
every 100 ms, and queues what it says on the link with the measurement's deadline
(capture time + ``ranging.max_age_ms``; the link checks it again at the last write).
What reached an autopilot is counted for the status line (:meth:`SendClock.delivery`):
a reading written while no autopilot is heard is not "sent". The clock also starts
the check of the autopilot's settings (:mod:`.settings_check`) against the range it
states (:meth:`SendClock.wire_range`).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import threading
import time
from typing import Callable

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.link.conditions import Condition
from uav_depth.daemon.link.contract import DistanceReport, distance_report, stamp_after, stamp_before, stated_range_cm
from uav_depth.daemon.link.endpoint import MavlinkLink
from uav_depth.daemon.link.settings import WireRange
from uav_depth.daemon.link.settings_check import SettingsCheck, attach
from uav_depth.daemon.link.vocabulary import HEARTBEAT_PERIOD_S, SENSOR_TYPES, orientation_code
from uav_depth.core.ranging import RangeLimits

from uav_depth.daemon.estimate import Estimate
log = logging.getLogger("uav_depth.mavlink")

#: A STATUSTEXT per condition change, at most this often.
STATUSTEXT_MIN_S = 1.0
#: The queue kind of ``mavlink.proximity_commit``'s copy: it replaces an unsent older copy, never a reading.
COMMIT_KIND = "DISTANCE_SENSOR commit"
#: The link's delivered counters the clock's readings add to (``count.delivered``).
READING, VALID = "reading", "valid reading"


class SendClock:
    """Sends each new estimate as soon as it exists, HEARTBEAT at 1 Hz, STATUSTEXT on condition changes.

    ``estimate``: returns the newest published estimate (a plain attribute read, never a lock
    the stereo loop holds); :meth:`notify` wakes the clock when one is published (until it is
    first called, the clock looks every 10 ms; then every 100 ms and on each notify).
    ``limits``: the current range limits; ``state``: the HEARTBEAT system state (boot,
    standby, active, critical, poweroff); ``blind``: the blind condition the service is in, or
    None while it measures.

    Each estimate is sent at most once, with time_boot_ms = its capture time; an estimate whose
    stamp is not later than the last one sent (serial-number order: right across the 49.7-day
    wrap) is never sent; at most ``mavlink.rate_hz`` DISTANCE_SENSOR per second (a newer estimate
    replaces one waiting for its slot). Blind: nothing is sent. ``mavlink.proximity_commit``:
    each reading is followed by its copy stamped 1 ms earlier (not counted in ``ticks``).
    """

    def __init__(self, link: MavlinkLink, config: MavlinkConfig, max_age_s: float,
                 estimate: Callable[[], Estimate | None], limits: Callable[[], RangeLimits],
                 state: Callable[[], str], clock: Callable[[], float] = time.monotonic,
                 blind: Callable[[], str | None] | None = None):
        self.link = link
        self.config = config
        self.max_age_s = max_age_s
        self.estimate = estimate
        self.limits = limits
        self.state = state
        self.blind = blind
        self.clock = clock
        self.t_start = 0.0                 # time_boot_ms counts from the companion's boot (CLOCK_MONOTONIC)
        self.orientation = orientation_code(config.orientation)
        self.sensor_type = SENSOR_TYPES[config.sensor_type]
        self.settings: SettingsCheck | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._notified = False
        self._thread: threading.Thread | None = None
        self._last_sent: Estimate | None = None
        self._last_stamp: int | None = None
        self._last_send_t = -math.inf
        self._told: Condition | None = None       # the condition the last STATUSTEXT announced
        self._told_t = -math.inf
        self.ticks = 0                     # DISTANCE_SENSOR queued
        self.valid_sent = 0                # of which measured distances
        self.condition = Condition.STARTING
        self.last_report: DistanceReport | None = None
        self.send_latency_ms: collections.deque[float] = collections.deque(maxlen=1000)   # capture -> queued

    def start(self) -> "SendClock":
        self.settings = attach(self.link, self.wire_range)
        self._thread = threading.Thread(target=self._loop, name="mavlink-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 1.0) -> bool:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def notify(self) -> None:
        """A new estimate was published: send it now."""
        self._notified = True
        self._wake.set()

    def wire_range(self) -> WireRange:
        """The range DISTANCE_SENSOR states now, and the orientation (what the autopilot's settings must fit)."""
        min_cm, max_cm = stated_range_cm(self.limits())
        return WireRange(min_cm, max_cm, self.orientation)

    def delivery(self, now: float | None = None) -> str:
        """The status line's account of what reached an autopilot: readings written while one was heard."""
        d, lost = self.link.count.delivered, self.link.count.lost[READING]
        ap = self.link.autopilot
        if ap is None:
            return f"NO AUTOPILOT HEARD on {self.link.config.url}: 0 of {self.ticks} readings delivered"
        heard = "" if self.link.autopilot_heard(now) else ", NOT HEARD NOW"
        return (f"sent {d[VALID]}/{d[READING]} valid to autopilot {ap[0]}/{ap[1]} "
                f"({self.ticks} readings made, {lost} lost{heard})")

    def tick(self, now: float) -> DistanceReport:
        """Evaluate the wire contract now; send the newest estimate if it is new and due."""
        est = self.estimate()
        blind = self.blind() if self.blind is not None else None
        report = distance_report(est, self.limits(), now, self.max_age_s, self.t_start, blind)
        self.condition = report.condition
        self.last_report = report
        if (report.sent and est is not None and est is not self._last_sent
                and (self._last_stamp is None or stamp_after(report.time_boot_ms, self._last_stamp))
                and now - self._last_send_t >= 1.0 / self.config.rate_hz):
            self._send(report, est)
            self._last_sent, self._last_stamp, self._last_send_t = est, report.time_boot_ms, now
            self.ticks += 1
            self.valid_sent += report.valid
            self.send_latency_ms.append((now - est.t_capture) * 1000.0)
        self._announce(now)
        return report

    def _send(self, report: DistanceReport, est: Estimate) -> None:
        tally = (READING, VALID) if report.valid else (READING,)
        args = (self.sensor_type, self.config.sensor_id, self.orientation, est.t_capture, self.max_age_s)
        self.link.distance_sensor(report, *args, tally=tally)
        if self.config.proximity_commit:
            # ArduPilot's MAVLink proximity backend keeps a reading pending until a message with
            # another time_boot_ms arrives: this copy (the same measurement, stamped 1 ms earlier,
            # so never newer than it is) closes it now instead of a frame later.
            copy = dataclasses.replace(report, time_boot_ms=stamp_before(report.time_boot_ms))
            self.link.distance_sensor(copy, *args, kind=COMMIT_KIND)

    def _announce(self, now: float) -> None:
        cond = self.condition
        if cond == self._told or now - self._told_t < STATUSTEXT_MIN_S:
            return
        if self.link.statustext(*cond.statustext):    # not connected yet: said once the link is up
            self._told, self._told_t = cond, now

    def heartbeat_state(self) -> str:
        state = self.state()
        return "critical" if state == "active" and self.condition.critical else state

    def _loop(self) -> None:
        next_hb = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            try:
                self.tick(now)
                if now >= next_hb:
                    self.link.heartbeat(self.heartbeat_state())
                    next_hb = now + HEARTBEAT_PERIOD_S      # late: the next one a period later, never a burst
            except Exception:   # the clock must keep ticking whatever one tick hit
                log.exception("mavlink: send tick failed")
            wait = min(0.1 if self._notified else 0.01, max(0.0, next_hb - now))
            slot = self._last_send_t + 1.0 / self.config.rate_hz - now
            if slot > 0:
                wait = min(wait, slot)
            self._wake.wait(wait)
            self._wake.clear()
