"""Reading the autopilot's settings back, once per autopilot, and saying what does not fit the wire's range.

When an ArduPilot or PX4 autopilot is first heard (its HEARTBEAT), every parameter
of its :mod:`.settings` rules is asked for with PARAM_REQUEST_READ; unanswered ones
are asked again each second. As soon as all are answered (or :data:`ANSWER_S` after
the first request, with what came) the rules are applied: each misfit is one
warning line in the log, and one STATUSTEXT names the first (and how many more).
Everything runs on the link's I/O thread, from its subscriptions (an autopilot sends
a HEARTBEAT every second, which paces the retries). One check per link (:func:`attach`):
``uav-depth sitl`` starts it when it connects, long before the service (and its send
clock) starts with the autopilot's pose.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Callable

from uav_depth.daemon.link.settings import LEGACY, RULES, WireRange, misfits

log = logging.getLogger("uav_depth.mavlink")

#: Give up waiting for unanswered parameters this long after the first request (they do not exist).
ANSWER_S = 2.5
#: Ask for an unanswered parameter again after this long.
RETRY_S = 0.8


def attach(link: Any, wire_range: Callable[[], WireRange]) -> "SettingsCheck":
    """The link's one check, started on first use; a later caller (the send clock, once the service runs)
    takes it over with its own ``wire_range``, and a check already done is not done again."""
    check = link.settings_check
    if check is None:
        check = link.settings_check = SettingsCheck(link, wire_range).start()
    check.wire_range = wire_range
    return check


class SettingsCheck:
    """Reads the autopilot's parameters through ``link`` and reports misfits against ``wire_range()``.

    ``link``: a :class:`~uav_depth.daemon.link.endpoint.MavlinkLink` (the STATUSTEXT goes out on
    it; the lines go to the log). ``result``: the misfit lines of the last check (None until one
    finished).
    """

    def __init__(self, link: Any, wire_range: Callable[[], WireRange], clock: Callable[[], float] = time.monotonic):
        self.link = link
        self.wire_range = wire_range
        self.clock = clock
        self._for: tuple[int, int] | None = None       # the autopilot being (or last) checked
        self._rules: tuple = ()
        self._values: dict[str, float] = {}
        self._asked: dict[str, float] = {}
        self._t0 = 0.0
        self._done = True
        self.result: list[str] | None = None
        self.finished_at: float | None = None

    def start(self) -> "SettingsCheck":
        self.link.subscribe("HEARTBEAT", self._on_heartbeat)
        self.link.subscribe("PARAM_VALUE", self._on_param)
        return self

    def _on_heartbeat(self, msg: Any) -> None:
        ap = self.link.autopilot
        if ap is None or (msg.get_srcSystem(), msg.get_srcComponent()) != ap:
            return
        if ap != self._for:
            self._begin(ap, int(msg.autopilot))
        elif not self._done:
            self._pace()

    def _begin(self, ap: tuple[int, int], stack: int) -> None:
        self._for, self._values, self._asked = ap, {}, {}
        self._rules = RULES.get(stack, ())
        if not self._rules:
            log.info("mavlink: autopilot system %d is neither ArduPilot nor PX4 (MAV_AUTOPILOT %d): its settings "
                     "are not checked", ap[0], stack)
            return
        self._t0, self._done = self.clock(), False
        for rule in self._rules:
            self._ask(rule.param)

    def _ask(self, name: str) -> None:
        if self.link.request_param(name):
            self._asked[name] = self.clock()

    def _pace(self) -> None:
        now = self.clock()
        if now - self._t0 >= ANSWER_S:
            self._finish()
            return
        for rule in self._rules:
            if rule.param not in self._values and now - self._asked.get(rule.param, -1e9) >= RETRY_S:
                self._ask(rule.param)

    def _on_param(self, msg: Any) -> None:
        if self._done or self._for is None or msg.get_srcSystem() != self._for[0]:
            return
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id
        if any(rule.param == name for rule in self._rules):
            self._values[name] = float(msg.param_value)
        wanted = {r.param for r in self._rules if r.param not in LEGACY}
        if wanted <= set(self._values):
            self._finish()
        else:
            self._pace()

    def _finish(self) -> None:
        self._done = True
        rng = self.wire_range()
        lines = misfits(self._rules, self._values, rng)
        self.result, self.finished_at = lines, self.clock()
        have = ", ".join(f"{k} {v:g}" for k, v in sorted(self._values.items()))
        if not self._values:
            log.warning("mavlink: the autopilot answered no PARAM_REQUEST_READ (%s): its settings are not checked",
                        ", ".join(r.param for r in self._rules))
            return
        if not lines:
            log.info("mavlink: the autopilot's settings fit the range on the wire (%.2f..%.2f m): %s",
                     rng.min_m, rng.max_m, have)
            return
        for line in lines:
            log.warning("mavlink: autopilot setting does not fit the range on the wire (%.2f..%.2f m): %s",
                        rng.min_m, rng.max_m, line)
        first = lines[0].split(";")[0].replace(" is ", " ")
        more = f" +{len(lines) - 1} more" if len(lines) > 1 else ""
        self.link.statustext(f"uav-depth: check {first}{more}", "warning")
