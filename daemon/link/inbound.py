"""What the link does with what it receives: a budget, the autopilot it hears, the subscribers.

:class:`ReadBudget` bounds the bytes parsed per second (a flood beyond it is left to
the kernel, which drops it, instead of taking the CPU from the stereo stage).
:class:`Dispatcher` notes the autopilot (its HEARTBEAT, and when it was last heard)
and hands every message to its subscribers on the I/O thread; message-interval
requests are remembered and sent again whenever the link reconnects or a (new)
autopilot appears, so they may be made before the autopilot is up.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Any, Callable

from uav_depth.daemon.link.peers import is_autopilot
from uav_depth.daemon.link.vocabulary import MAV_CMD_SET_MESSAGE_INTERVAL

log = logging.getLogger("uav_depth.mavlink")

Callback = Callable[[Any], None]
#: Inbound bytes parsed per second, at most (a token bucket with a burst of READ_BURST): well above what
#: an autopilot sends (tens of KB/s with every stream on).
READ_RATE = 128 * 1024
READ_BURST = 32 * 1024
#: An autopilot is "heard" while its last HEARTBEAT is at most this old (both stacks send one a second).
HEARD_S = 3.0


class ReadBudget:
    """A token bucket of inbound bytes."""

    def __init__(self, now: float, rate: float = READ_RATE, burst: float = READ_BURST):
        self.rate, self.burst = rate, burst
        self.tokens, self._t = float(burst), now

    def refill(self, now: float) -> bool:
        """Add what ``now`` earned; True while there is budget to read."""
        self.tokens = min(self.burst, self.tokens + (now - self._t) * self.rate)
        self._t = now
        return self.tokens > 0

    def spend(self, n: int) -> None:
        self.tokens -= n


class Dispatcher:
    """Subscriptions, the autopilot heard, and remembered interval requests.

    ``send(build)`` queues a message (the link's ``send``); ``target_system`` /
    ``target_component``: the configured autopilot (0: the one heard).
    """

    def __init__(self, send: Callable[[Callable[[Any], Any]], bool], target_system: int, target_component: int):
        self._send = send
        self.target_system, self.target_component = target_system, target_component
        self._subs: dict[str, list[Callback]] = {}
        self._lock = threading.Lock()
        self._intervals: dict[int, float] = {}
        self.autopilot: tuple[int, int] | None = None
        self.autopilot_type: int | None = None      # HEARTBEAT.autopilot (MAV_AUTOPILOT) of the one heard
        self.heard_at = -math.inf                   # monotonic s of its last HEARTBEAT

    def heard(self, now: float) -> bool:
        """True while the autopilot's last HEARTBEAT is at most :data:`HEARD_S` old."""
        return now - self.heard_at <= HEARD_S

    def subscribe(self, msg_type: str, callback: Callback) -> Callable[[], None]:
        with self._lock:
            self._subs.setdefault(msg_type, []).append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subs.get(msg_type, []):
                    self._subs[msg_type].remove(callback)
        return unsubscribe

    def target(self) -> tuple[int, int]:
        auto = self.autopilot or (1, 1)
        return (self.target_system or auto[0], self.target_component or auto[1])

    def request_interval(self, msg_id: int, hz: float) -> None:
        self._intervals[msg_id] = hz
        self._send_interval(msg_id, hz)

    def resend_intervals(self) -> None:
        for msg_id, hz in list(self._intervals.items()):
            self._send_interval(msg_id, hz)

    def _send_interval(self, msg_id: int, hz: float) -> None:
        interval_us = 1e6 / hz if hz > 0 else -1.0
        sysid, compid = self.target()
        self._send(lambda mav: mav.command_long_encode(sysid, compid, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                       float(msg_id), interval_us, 0, 0, 0, 0, 0))

    def dispatch(self, msg: Any, now: float) -> None:
        """Note an autopilot's HEARTBEAT, then call every subscriber of the message's type (and of "*")."""
        mtype = msg.get_type()
        if is_autopilot(msg, self.target_system):
            ap = (msg.get_srcSystem(), msg.get_srcComponent())
            self.heard_at = now
            self.autopilot_type = int(msg.autopilot)
            if ap != self.autopilot:
                log.info("mavlink: autopilot found: system %d component %d", *ap)
                self.autopilot = ap
                self.resend_intervals()
        with self._lock:
            callbacks = list(self._subs.get(mtype, ())) + list(self._subs.get("*", ()))
        for cb in callbacks:
            try:
                cb(msg)
            except Exception:   # a subscriber's bug must not kill the link
                log.exception("mavlink: subscriber for %s failed", mtype)
