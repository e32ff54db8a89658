"""Log lines the link writes under floods and retries: one per kind of event, at most every few seconds.

A peer that sends thousands of bad datagrams a second, or a port that stays
missing, must not flood journald; what was left out is counted into the next line.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Callable

#: A kind of event is logged at most this often.
EVERY_S = 10.0


class RateLimitedLog:
    """``log.warning``-like calls, at most one line per ``key`` every ``every_s``; the next line says how
    many were left out. A new ``text`` for a key (a different problem) is logged at once."""

    def __init__(self, logger: logging.Logger, every_s: float = EVERY_S,
                 clock: Callable[[], float] = time.monotonic):
        self.log = logger
        self.every_s = every_s
        self.clock = clock
        self._last: dict[str, tuple[float, str]] = {}
        self._left_out: dict[str, int] = {}
        self.lines = 0

    def __call__(self, level: int, key: str, text: str, *args: Any, exc_info: bool = False) -> bool:
        """Log ``text % args`` at ``level`` unless ``key`` was logged with the same text within
        ``every_s``; True when a line was written."""
        now = self.clock()
        last = self._last.get(key)
        if last is not None and last[1] == text and now - last[0] < self.every_s:
            self._left_out[key] = self._left_out.get(key, 0) + 1
            return False
        n = self._left_out.pop(key, 0)
        suffix = f" ({n} more like it in the last {now - last[0]:.0f} s)" if n and last is not None else ""
        self.log.log(level, (text % args if args else text) + suffix, exc_info=exc_info)
        self._last[key] = (now, text)
        self.lines += 1
        return True

    def forget(self, key: str) -> None:
        """The problem ``key`` is over: its next occurrence is logged at once."""
        self._last.pop(key, None)
        self._left_out.pop(key, None)
