"""The link's I/O thread: one transport, written from the send queue, read into the dispatcher.

:class:`Pump` is what the thread of :class:`~.endpoint.MavlinkLink` runs: it opens
the transport (and reopens it, at most every 0.25 s), and each turn writes the queue
(every message checked against its deadline at the moment it is written; on TCP,
measurements only through the read gate of :mod:`.peers`), discards what the kernel
holds past its deadline, and reads a bounded amount (udpin: through the owner of
:mod:`.peers`). It survives its own bugs: a message whose builder raises is dropped
and counted (``build_errors``, one log line); an unexpected error in a turn is logged
and the next turn goes on.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
from typing import Any, Callable

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.link import messages
from uav_depth.daemon.link.inbound import Dispatcher, ReadBudget
from uav_depth.daemon.link.lines import RateLimitedLog
from uav_depth.daemon.link.peers import ReadGate, UdpinOwner, Verdict
from uav_depth.daemon.link.queue import LinkCounters, Out, SendQueue
from uav_depth.daemon.link.signing import Signing
from uav_depth.daemon.link.streams import Stream, TcpClient, TcpServer
from uav_depth.daemon.link.transport import Transport, UdpIn
from uav_depth.daemon.link.urls import open_transport

log = logging.getLogger("uav_depth.mavlink")


def wait_readable(fds: list[int], timeout_s: float) -> list[int]:
    try:
        r, _, _ = select.select(fds, [], [], max(0.0, timeout_s))
    except (OSError, ValueError):
        return []
    return r


class Pump:
    """The I/O thread's work (module docstring). ``t``: the open transport, or None; written by the thread."""

    def __init__(self, config: MavlinkConfig, signing: Signing, queue: SendQueue, counters: LinkCounters,
                 inbound: Dispatcher, backoff: tuple[float, float], clock: Callable[[], float]):
        self.config = config
        self.signing = signing
        self._queue = queue
        self.count = counters
        self._inbound = inbound
        self._backoff = backoff
        self._clock = clock
        self._lines = RateLimitedLog(log)
        self._gate = ReadGate(self._ask, self._lines, config.url)
        self._owner = UdpinOwner(config.url, config.target_system, signing, self._lines)
        self._budget = ReadBudget(clock())
        self._t: Transport | None = None
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)

    @property
    def t(self) -> Transport | None:
        return self._t

    def wake(self) -> None:
        """Make the thread turn now (something was queued, or it should stop)."""
        try:
            os.write(self._wake_w, b"\0")
        except (BlockingIOError, OSError):   # already awake (pipe full) or closed
            pass

    def run(self, stop: threading.Event) -> None:
        """The I/O thread: connect, turn until ``stop``, then write the last words."""
        delay = self._backoff[0]
        while not stop.is_set():
            if self._t is None:
                delay = self._connect(delay, stop)
                continue
            try:
                self._turn(self._t)
            except (ConnectionError, OSError) as exc:   # serial unplugged, socket error, peer gone
                if not stop.is_set():
                    self.close_transport()
                    self._lines(logging.WARNING, "lost", "mavlink %s: link lost (%s); reconnecting",
                                self.config.url, f"{type(exc).__name__}: {exc}")
            except Exception:   # a bug in one turn must not end the link: said, and the next turn goes on
                self._lines(logging.ERROR, "turn", "mavlink %s: an I/O turn failed", self.config.url,
                            exc_info=True)
                stop.wait(0.01)
        if self._t is not None:
            try:
                self._write_queue(self._t)    # the last words (STATUSTEXT, HEARTBEAT poweroff)
            except (ConnectionError, OSError):
                pass

    def _connect(self, delay: float, stop: threading.Event) -> float:
        """Open the transport; the next delay (doubling up to the back-off's maximum while it fails)."""
        c = self.config
        try:
            t = open_transport(c.url, c.baud, c.bind_address)
        except (OSError, ValueError, ConnectionError) as exc:   # refused, no device, port in use
            self._lines(logging.WARNING, "connect", "mavlink %s: cannot connect (%s); retrying every %.2f s at most",
                        c.url, f"{type(exc).__name__}: {exc}", self._backoff[1])
            stop.wait(delay)
            return min(delay * 2, self._backoff[1])
        self._lines.forget("connect")
        self._lines.forget("lost")
        if isinstance(t, UdpIn):
            self._owner.adopt(t)
        self._t = t
        self.count.connects += 1
        log.info("mavlink %s: connected (%s) as system %d component %d", c.url, t.description, c.system_id,
                 c.component_id)
        self._new_connection()
        return self._backoff[0]

    def close_transport(self) -> None:
        t, self._t = self._t, None
        if t is not None:
            try:
                t.close()
            except OSError:   # closing a dead port must not fail a shutdown
                pass

    def _new_connection(self) -> None:
        self.signing.reset_stream()
        self._gate.reset()
        self._inbound.resend_intervals()

    def _turn(self, t: Transport) -> None:
        """One turn: accept, write the queue, check the kernel's backlog, read a bounded amount."""
        t.poll()
        if isinstance(t, TcpServer) and t.new_connection():
            log.info("mavlink %s: peer connected", self.config.url)
            self._new_connection()
        if isinstance(t, UdpIn):
            self._owner.listen(t, self._clock())
        self._write_queue(t)
        if isinstance(t, Stream) and t.overdue(self._clock()):
            t.discard()          # what the kernel still holds has expired: it must not arrive
            self.count.discards += 1
            self._lines(logging.WARNING, "overdue", "mavlink %s: peer not taking data: unsent messages expired "
                        "and were discarded", self.config.url)
        if t.dead:
            raise ConnectionError("connection reset")
        now = self._clock()
        pending = self._queue.any_ready()     # otherwise waiting for an answer: the socket wakes us
        reading = self._budget.refill(now)    # over the inbound budget: the kernel holds (or drops) it
        fds = [t.fileno(), self._wake_r] if reading else [self._wake_r]
        ready = wait_readable(fds, 0.0 if pending else (0.05 if reading else 0.02))
        if self._wake_r in ready:
            try:
                os.read(self._wake_r, 4096)
            except BlockingIOError:
                pass
        if reading and t.fileno() in ready:
            self._budget.spend(self._read(t))

    def _ask(self, now: float) -> int | None:
        """Write a TIMESYNC request now (the read gate's question); its ts1, or None."""
        ts1 = time.monotonic_ns()
        t = self._t
        if t is None or not t.write(self.signing.pack(messages.timesync_request(ts1)(self.signing.tx)), None, now):
            return None
        return ts1

    def _write_queue(self, t: Transport) -> None:
        gated = isinstance(t, (TcpClient, TcpServer))
        waiting: list[Out] = []
        for o in self._queue.take():
            now = self._clock()
            if o.deadline is not None and now > o.deadline:
                self.count.drop("expired", o)
            elif not t.can_send:
                self.count.drop("dropped", o)
            elif o.deadline is not None and gated and (verdict := self._gate.decide(o, now)) is not Verdict.WRITE:
                if verdict is Verdict.WAIT:
                    waiting.append(o)
                else:
                    self.count.drop("held", o)               # not reading: held back, not queued
            else:
                self._write_one(t, o, now)
        self._queue.put_back(waiting)

    def _write_one(self, t: Transport, o: Out, now: float) -> None:
        try:
            buf = self.signing.pack(o.build(self.signing.tx))
        except Exception:   # a builder's bug drops its message, never the I/O thread
            self.count.drop("build_errors", o)
            self._lines(logging.ERROR, "build", "mavlink %s: a %s message could not be built and was dropped",
                        self.config.url, o.kind or "queued", exc_info=True)
            return
        if not t.write(buf, o.deadline, now):
            self.count.drop("dropped", o)
            return
        self.count.sent += 1
        if o.tally and self._inbound.heard(now):
            self.count.delivered.update(o.tally)

    def _read(self, t: Transport) -> int:
        """Parse what is there (bounded by the transport's read budget); the number of bytes read."""
        got = t.read()
        for data, addr in got:
            if isinstance(t, UdpIn) and addr != t.peer:
                msg = self._owner.candidate(t, data, addr)
                if msg is not None:
                    self._new_connection()
                    self._handle(msg)
                continue
            for msg in self.signing.rx.parse_buffer(data) or ():
                if msg.get_type() == "BAD_DATA":
                    self.count.bad += 1
                else:
                    self._handle(msg)
        return sum(len(data) for data, _ in got)

    def _handle(self, msg: Any) -> None:
        self.count.received += 1
        if msg.get_type() == "TIMESYNC":
            self._gate.on_timesync(msg)
        self._inbound.dispatch(msg, self._clock())
