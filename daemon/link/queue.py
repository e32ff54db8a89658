"""The send queue between the threads that send and the link's I/O thread, and the link's counters.

Bounded and droppable: a newer message of a kind replaces an unsent older one, the
oldest goes when it is full, and a message is built and deadline-checked only at
the moment of writing (never written after its deadline).
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

#: Messages waiting to be written, at most (the oldest is dropped first).
QUEUE_MAX = 32


@dataclass
class Out:
    """One message waiting: ``build(mav)`` makes it when it is written (on the I/O thread).

    ``kind``: a newer Out of the same kind replaces this one while it waits.
    ``deadline``: monotonic s after which it is never written (a measurement's capture
    time + ``ranging.max_age_ms``); None: no deadline. ``tally``: the counters of
    :attr:`LinkCounters.delivered` it adds to when written while an autopilot is heard.
    """

    kind: str | None
    build: Callable[[Any], Any]
    deadline: float | None
    tally: tuple[str, ...] = ()
    probe: int | None = None      # TCP: the TIMESYNC request (ts1) this measurement waits to see answered


@dataclass
class LinkCounters:
    """What the link did, for the status line, tests and benchmarks (written by the I/O thread)."""

    sent: int = 0
    dropped: int = 0          # queued but not written: no connection or peer, queue full, replaced
    expired: int = 0          # not written because its deadline had passed
    held: int = 0             # measurements held back: the TCP peer did not show it was reading
    discards: int = 0         # times the kernel's unsent bytes were thrown away (they had expired)
    received: int = 0
    bad: int = 0              # frames the parser could not use (BAD_DATA): junk, bad CRC, bad signature
    connects: int = 0
    build_errors: int = 0     # messages dropped because building them raised (a bug, logged)
    #: Written while an autopilot was heard, by tally (see :class:`Out`): "sent means delivered".
    delivered: collections.Counter = field(default_factory=collections.Counter)
    #: Not written at all (replaced, expired, held back, no peer, a failed write), by tally.
    lost: collections.Counter = field(default_factory=collections.Counter)

    def drop(self, why: str, out: "Out | None" = None) -> None:
        """Count a message not written: ``why`` names the counter (dropped, expired, held, build_errors)."""
        setattr(self, why, getattr(self, why) + 1)
        if out is not None:
            self.lost.update(out.tally)


class SendQueue:
    """Thread-safe: :meth:`put` from any thread; :meth:`take` and :meth:`put_back` from the I/O thread."""

    def __init__(self, counters: LinkCounters, limit: int = QUEUE_MAX):
        self._items: collections.deque[Out] = collections.deque()
        self._lock = threading.Lock()
        self._limit = limit
        self._counters = counters

    def put(self, out: Out) -> None:
        with self._lock:
            if out.kind is not None:
                for i, o in enumerate(self._items):
                    if o.kind == out.kind:
                        del self._items[i]
                        self._counters.drop("dropped", o)
                        break
            if len(self._items) >= self._limit:
                self._counters.drop("dropped", self._items.popleft())
            self._items.append(out)

    def take(self) -> list[Out]:
        """Everything waiting, oldest first; the queue is empty after."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    def put_back(self, waiting: list[Out]) -> None:
        """Return messages still waiting (for a TIMESYNC answer) to the front, unless a newer one of
        their kind was queued meanwhile."""
        if not waiting:
            return
        with self._lock:
            kinds = {o.kind for o in self._items}
            self._items.extendleft(o for o in reversed(waiting) if o.kind not in kinds)

    def any_ready(self) -> bool:
        """True when something waits that is not waiting for a TIMESYNC answer (write it without sleeping)."""
        with self._lock:
            return any(o.probe is None for o in self._items)
