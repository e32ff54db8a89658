"""A background thread of the runtime that must yield the CPU to the stereo loop.

The rig check and the OBSTACLE_DISTANCE pass each run one such thread: started
with the service's stop event, niced (Linux nices one thread by its id; where
that is refused, as under the unit's syscall filter, it runs at the daemon's
priority), and joined with a bound at shutdown.
"""

from __future__ import annotations

import logging
import os
import threading


class NicedWorker:
    """``_loop(stop)`` on a daemon thread named ``NAME`` at niceness ``NICENESS``."""

    NAME = "worker"
    NICENESS = 10
    _thread: threading.Thread | None = None

    def start(self, stop: threading.Event):
        self._thread = threading.Thread(target=self._run, args=(stop,), name=self.NAME, daemon=True)
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        """The thread runs (it ends only when the stop event is set, or by dying)."""
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout_s: float) -> bool:
        """True when the thread is gone (or never started) within ``timeout_s``."""
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self, stop: threading.Event) -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self.NICENESS)
        except (AttributeError, OSError):
            logging.getLogger(type(self).__module__).debug("%s runs at the daemon's priority", self.NAME)
        self._loop(stop)

    def _loop(self, stop: threading.Event) -> None:
        raise NotImplementedError
