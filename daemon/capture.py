"""The capture thread: the source into a one-slot mailbox, and reconnecting when the camera is lost.

The newest frame wins: older ones are dropped (counted), never queued, so the
stereo stage always works on the latest view; a source with ``lossless`` true (replay
for evaluation) waits for the slot instead, so every frame is processed. Camera loss (a SourceError, any
driver error, or no frame for ``service.frame_timeout_s``): close, reopen with
exponential back-off between ``reconnect_min_s`` and ``reconnect_max_s``; the loss and
the return are written to the shared state, which the service's condition reads.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from uav_depth.core.errors import SourceError
from uav_depth.daemon.config import ServiceConfig
from uav_depth.daemon.sources import EndOfStream, Frame, FrameSource
from uav_depth.daemon.state import ServiceState

log = logging.getLogger("uav_depth.service")


class Mailbox:
    """One slot: ``put`` replaces what is there (counting the drop), ``get`` waits for something new."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Frame | None = None
        self.dropped = 0

    def put(self, item: Frame, wait_for_room: threading.Event | None = None) -> None:
        """Place ``item``; with ``wait_for_room`` (a stop event), first wait until the slot is empty
        (lossless: nothing is dropped, the source waits for the pipeline) unless the event is set."""
        with self._cond:
            if wait_for_room is not None:
                while self._item is not None and not wait_for_room.is_set():
                    self._cond.wait(0.1)
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self._cond.notify_all()

    def get(self, timeout_s: float) -> Frame | None:
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            self._cond.notify_all()    # a lossless put waits for the slot to empty
            return item


class Capture:
    """The body of the ``capture`` thread (:meth:`run`) until the stop event is set or the source ends.

    It writes its fields of the shared :class:`~uav_depth.daemon.state.ServiceState`
    (``camera_ok``, ``camera_losses``, ``ended``, ``source_since``) and says a loss and a
    return in one log line and one STATUSTEXT each (``announce(text, severity)``).
    """

    def __init__(self, source: FrameSource, config: ServiceConfig, mailbox: Mailbox, state: ServiceState,
                 announce: Callable[[str, str], object]):
        self.source = source
        self.config = config
        self.mailbox = mailbox
        self.state = state
        self.stop = state.stopping
        self.announce = announce
        self.frames_in = 0
        self._thread = threading.Thread(target=self.run, name="capture", daemon=True)

    def start(self) -> "Capture":
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        """Reading, or ended with a finite source (the only way it ends before shutdown, but dying)."""
        return self._thread.is_alive() or self.state.ended is not None

    def join(self, timeout_s: float) -> bool:
        if self._thread.ident is not None:
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def reconnect(self) -> None:
        svc = self.config
        delay = svc.reconnect_min_s
        try:
            self.source.close()
        except Exception:   # a vanished device may fail to close; we reopen anyway
            log.debug("source close failed", exc_info=True)
        while not self.stop.is_set():
            if self.stop.wait(delay):
                return
            try:
                with self.state.in_source():
                    self.source.open()
                return
            except SourceError as exc:
                log.info("camera still missing (%s); next try in %.1f s", exc, min(delay * 2, svc.reconnect_max_s))
            except Exception as exc:   # a driver error while reopening is the same story
                log.info("camera reopen failed (%s: %s)", type(exc).__name__, exc)
            delay = min(delay * 2, svc.reconnect_max_s)

    def _lost(self, why: str) -> float:
        st = self.state
        if st.camera_ok:
            st.camera_ok = False
            st.camera_losses += 1
            log.error("camera lost: %s; reconnecting (no measurement is sent meanwhile)", why)
            self.announce("uav-depth: camera lost", "error")
        self.reconnect()
        return time.monotonic()

    def _arrived(self) -> None:
        if not self.state.camera_ok:
            self.state.camera_ok = True
            log.info("camera back: %s", self.source.describe())
            self.announce("uav-depth: camera back", "notice")

    def run(self) -> None:
        """Read until stopped; the source is open when this starts (start-up opened it)."""
        svc = self.config
        self.state.camera_ok = True
        last = time.monotonic()
        while not self.stop.is_set():
            try:
                with self.state.in_source():
                    frame = self.source.read(min(0.2, svc.frame_timeout_s))
            except EndOfStream as exc:
                log.info("%s", exc)
                self.state.ended = str(exc)
                return
            except SourceError as exc:
                last = self._lost(str(exc))
                continue
            except Exception as exc:   # an unexpected driver error is a lost camera too
                log.exception("source read failed")
                last = self._lost(f"{type(exc).__name__}: {exc}")
                continue
            now = time.monotonic()
            if frame is None:
                if now - last > svc.frame_timeout_s:
                    last = self._lost(f"no frame for {now - last:.1f} s")
                continue
            last = now
            self.frames_in += 1
            self._arrived()
            # A lossless source (replay with source.lossless) waits for the pipeline instead of dropping.
            self.mailbox.put(frame, self.stop if getattr(self.source, "lossless", False) else None)
