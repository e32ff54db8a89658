"""Who the link talks to: the one udpin owner, and the proof that a TCP peer is reading.

**The udpin owner.** ``udpin`` answers one autopilot: the address of the first
HEARTBEAT from an autopilot (``autopilot`` not MAV_AUTOPILOT_INVALID) whose system
id is ``mavlink.target_system`` (any, when 0). That address owns the stream for the
link's life: a HEARTBEAT alone never takes it over, however long the owner is silent
(an unsigned HEARTBEAT proves nothing about who sent it). With signing, a new address
may take the stream once the owner has been silent for :data:`PEER_SILENT_S`, with an
autopilot HEARTBEAT signed with the key and newer than every frame seen on its stream
(so a replay cannot). Without signing, an operator re-binds by restarting the daemon.

**The TCP read gate.** A TCP peer that stops reading without closing the connection
still has its kernel acknowledge our bytes, which then wait in *its* receive buffer
and arrive old when it resumes. So on TCP a measurement is written only after the
peer answered a TIMESYNC request (``tc1`` 0, answered by ArduPilot and PX4 on the same
link) sent just before it: a peer answers only while its application reads. A peer
that does not answer (within :data:`PROBE_TIMEOUT_S`), or whose answer our signing
refuses, gets no measurement at all; a new request goes out every
:data:`PROBE_AGAIN_S`.
"""

from __future__ import annotations

import enum
import logging
from typing import Any, Callable

from uav_depth.daemon.link.lines import RateLimitedLog
from uav_depth.daemon.link.queue import Out
from uav_depth.daemon.link.signing import Signing
from uav_depth.daemon.link.transport import UdpIn
from uav_depth.daemon.link.vocabulary import MAV_AUTOPILOT_INVALID

#: A udpin owner silent this long may be replaced, with signing only, by a signed autopilot HEARTBEAT.
PEER_SILENT_S = 3.0
#: A TIMESYNC request unanswered this long: the peer is not reading, measurements are held back.
PROBE_TIMEOUT_S = 0.1
#: While held back, a new request this often.
PROBE_AGAIN_S = 1.0


def is_autopilot(msg: Any, target_system: int) -> bool:
    """A HEARTBEAT from a flight controller (of ``target_system``, if not 0)."""
    return (msg.get_type() == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID
            and (not target_system or msg.get_srcSystem() == target_system))


class UdpinOwner:
    """Binds a :class:`UdpIn` to its one peer (see the module docstring); :meth:`candidate` parses a
    datagram from any other address, and binds its sender if it may own the stream."""

    def __init__(self, url: str, target_system: int, signing: Signing, lines: RateLimitedLog):
        self.url = url
        self.target_system = target_system
        self.signing = signing
        self.lines = lines
        self.peer: tuple[str, int] | None = None     # the owner, for the link's life (a reconnect keeps it)
        self.refused = 0          # datagrams from addresses that may not take the stream

    def adopt(self, t: UdpIn) -> None:
        """A new udpin socket (after a socket error): the owner stays the owner."""
        if self.peer is not None:
            t.bind_peer(self.peer)

    def listen(self, t: UdpIn, now: float) -> None:
        """Tell the transport whether datagrams from other addresses are worth reading now."""
        t.hear_strangers = t.peer is None or (self.signing.enabled and now - t.peer_heard > PEER_SILENT_S)

    def candidate(self, t: UdpIn, data: bytes, addr: Any) -> Any | None:
        """The autopilot HEARTBEAT that bound ``addr`` (the link dispatches it and starts afresh), or None."""
        for msg in self.signing.fresh_parser().parse_buffer(data) or ():
            if msg.get_type() != "BAD_DATA" and is_autopilot(msg, self.target_system):
                was = t.peer
                t.bind_peer(addr)
                self.peer = addr
                if was is None:
                    self.lines(logging.INFO, "bind", "mavlink %s: answering the autopilot at %s:%d (system %d) "
                               "only", self.url, addr[0], addr[1], msg.get_srcSystem())
                else:
                    self.lines(logging.WARNING, "rebind", "mavlink %s: the autopilot at %s:%d was silent; a "
                               "signed HEARTBEAT of system %d at %s:%d owns the stream now", self.url, was[0],
                               was[1], msg.get_srcSystem(), addr[0], addr[1])
                return msg
        self.refused += 1
        self.lines(logging.WARNING, "stranger", "mavlink %s: ignoring datagrams from %s:%d (%s)", self.url,
                   addr[0], addr[1], "no autopilot HEARTBEAT" + (" signed with our key" if self.signing.enabled
                                                                 else ""))
        return None


class Verdict(enum.Enum):
    WRITE = "write"
    WAIT = "wait"      # its TIMESYNC request is out, within the timeout: keep it queued
    HOLD = "hold"      # the peer is not showing that it reads: dropped, counted as held


class ReadGate:
    """The TCP read gate (module docstring). ``ask(now)`` sends a TIMESYNC request and returns its ts1
    (None when it could not be written)."""

    def __init__(self, ask: Callable[[float], int | None], lines: RateLimitedLog, url: str):
        self._ask = ask
        self.lines = lines
        self.url = url
        self.reset()

    def reset(self) -> None:
        """A new connection: nothing asked, nothing answered."""
        self._probe: tuple[int, float] | None = None      # (ts1, sent at) of the unanswered request
        self._answered = 0                                # ts1 of the newest answered request
        self.answers = 0

    def on_timesync(self, msg: Any) -> None:
        """An answer (``tc1`` != 0) to our outstanding request opens the gate for what waited on it."""
        if msg.tc1 != 0 and self._probe is not None and msg.ts1 == self._probe[0]:
            self._answered, self._probe = msg.ts1, None
            self.answers += 1
            self.lines.forget("not reading")

    def _request(self, now: float) -> int | None:
        ts1 = self._ask(now)
        if ts1 is not None:
            self._probe = (ts1, now)
        return ts1

    def decide(self, o: Out, now: float) -> Verdict:
        """Whether measurement ``o`` may be written now."""
        if o.probe is None:
            if self._probe is not None and now - self._probe[1] >= PROBE_TIMEOUT_S:
                if now - self._probe[1] >= PROBE_AGAIN_S:
                    self._request(now)                # ask again now and then
                self._not_reading()
                return Verdict.HOLD
            o.probe = self._probe[0] if self._probe is not None else self._request(now)
            if o.probe is None:
                return Verdict.HOLD
        if self._answered >= o.probe:
            return Verdict.WRITE
        if self._probe is not None and self._probe[0] == o.probe and now - self._probe[1] < PROBE_TIMEOUT_S:
            return Verdict.WAIT
        self._not_reading()
        return Verdict.HOLD

    def _not_reading(self) -> None:
        self.lines(logging.WARNING, "not reading", "mavlink %s: the TCP peer answers no TIMESYNC request (%s): "
                   "measurements are held back, since they could wait in its buffer and arrive old", self.url,
                   "never so far" if self.answers == 0 else "not now")
