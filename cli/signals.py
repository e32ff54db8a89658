"""The daemon's signal handlers, installed first thing (before any slow import) and only setting events.

``uav-depth run`` and ``sitl`` take seconds to import NumPy, OpenCV and pymavlink
and to open the camera. A signal in that window would meet Python's defaults:
SIGHUP and SIGUSR1 kill the process silently, SIGINT gives a KeyboardInterrupt
traceback, SIGTERM exits -15. :func:`install` runs in :func:`uav_depth.cli.main.entry`
before the subcommand table is even built, and then unblocks the signals: the systemd
unit starts the daemon with them blocked (``env --block-signal=HUP,INT,TERM,USR1``), so
one sent while the interpreter itself starts waits for the handlers instead of killing
the process. From then on:

- SIGTERM, SIGINT: set :attr:`Signals.stop`; the command stops cleanly (exit 0)
  at its next check, or the service's main loop does;
- SIGHUP: a reload request; before the service runs it is moot (the parameter
  file is read at start-up) and is logged as such; afterwards it reaches
  :meth:`~uav_depth.daemon.service.Service.request_reload`;
- SIGUSR1: a frame-log request, handed to the service once it runs.

This module imports only the standard library's signal, threading, os and time.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Callable

HANDLED = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGUSR1)


def ms_since_exec() -> float | None:
    """Milliseconds since this process started (``/proc/self/stat`` start time), None where unknown.

    The kernel records the start in clock ticks (10 ms on most kernels), so this is
    accurate to about 10 ms.
    """
    try:
        with open("/proc/self/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        start_s = int(fields[19]) / os.sysconf("SC_CLK_TCK")
        return (time.clock_gettime(time.CLOCK_BOOTTIME) - start_s) * 1000.0
    except (OSError, ValueError, IndexError, AttributeError):
        return None


class Signals:
    """Events the handlers set; :meth:`attach` later routes SIGHUP/SIGUSR1 to the service."""

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.reload = threading.Event()
        self.log_frame = threading.Event()
        self.received: list[str] = []          # names, in order (for the start-up log)
        self.installed_after_ms: float | None = None
        self.at_exec = False                   # installed by entry(), before the slow imports
        self.held: list[str] = []              # signals that arrived blocked, before the handlers were in
        self._on_reload: Callable[[], None] | None = None
        self._on_log_frame: Callable[[], None] | None = None

    def _handle(self, signum: int, _frame: object) -> None:
        # Only set events (and append to a list): no locks, no I/O, no logging.
        self.received.append(signal.Signals(signum).name)
        if signum in (signal.SIGTERM, signal.SIGINT):
            self.stop.set()
        elif signum == signal.SIGHUP:
            self.reload.set()
            if self._on_reload is not None:
                self._on_reload()
        elif signum == signal.SIGUSR1:
            self.log_frame.set()
            if self._on_log_frame is not None:
                self._on_log_frame()

    def install(self, at_exec: bool = False) -> "Signals":
        """Install the handlers (main thread only), then unblock the signals; records how long after exec.

        The systemd unit starts the daemon with these signals blocked (``env --block-signal``), so one
        that arrives while Python starts, before any handler can exist, waits instead of killing the
        process silently (SIGINT: with a traceback); unblocking hands it to the handler now.
        """
        for sig in HANDLED:
            signal.signal(sig, self._handle)
        self.at_exec = at_exec
        self.installed_after_ms = ms_since_exec()
        self.held = sorted(sig.name for sig in signal.sigpending() if sig in HANDLED)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, HANDLED)
        return self

    def attach(self, on_reload: Callable[[], None], on_log_frame: Callable[[], None]) -> None:
        """From now on SIGHUP calls ``on_reload`` and SIGUSR1 ``on_log_frame`` (both must only set events).

        A SIGUSR1 that came earlier is handed over now; an earlier SIGHUP is dropped
        (what it asked for, reading the parameter file, happens at start-up).
        """
        self._on_reload, self._on_log_frame = on_reload, on_log_frame
        self.reload.clear()
        if self.log_frame.is_set():
            on_log_frame()


#: The process's handlers (installed by :func:`uav_depth.cli.main.entry` for run and sitl).
SIGNALS = Signals()


def install_once() -> Signals:
    """:data:`SIGNALS` when ``entry`` installed them at exec; else fresh handlers installed now
    (a caller running ``main([...])`` in-process gets new events for each run)."""
    return SIGNALS if SIGNALS.at_exec else Signals().install()
