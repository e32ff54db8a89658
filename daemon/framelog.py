"""Background frame logging in the log layout, for tuning (``uav-depth tune``/``evaluate`` read it as is).

Every ``every_n``-th processed frame, and the next frame after :meth:`FrameLogger.request`
(SIGUSR1), is queued for a writer thread; the frame loop never waits: when the
queue is full the frame is dropped and counted. Frames are logged *rectified*,
with the rectified calibration, so the tuner scores exactly what the daemon
matched. Each run writes one session directory ``YYYYmmdd-HHMMSS-<source>``.

Disk budget (``max_mb`` for the whole log directory): before each frame the
oldest *other* sessions are removed until the frame fits; when the current
session alone fills the budget, logging stops. Free space (``min_free_mb``): a frame
that would leave less than that free on the log's file system is not written and
logging stops (other users of the disk count too, so the budget alone cannot
promise it). Any write error (disk full, read-only, quota) stops logging with one
warning; the daemon keeps flying. A log directory that cannot be created or written
at start-up is a configuration error (:func:`ensure_log_dir`).
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError
from uav_depth.daemon.config import LoggingConfig
from uav_depth.core.session import Session, SessionWriter
from uav_depth.daemon.estimate import Estimate
from uav_depth.core.frames import Frame

log = logging.getLogger("uav_depth.framelog")


def frame_meta(frame: Frame, est: Estimate, t0: float, source_kind: str,
               roi: tuple[int, int, int, int] | None) -> dict[str, Any]:
    """The ``meta`` a logged frame carries: when, what was measured, with which parameters, how long it took.

    ``t0``: the service's start (monotonic s), so ``time_s`` counts from it. The
    source's own ``frame.meta`` keys are added where they do not clash.
    """
    m = est.measurement
    meta: dict[str, Any] = {
        "time_s": round(frame.t_capture - t0, 6),
        "wall_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "index": frame.index, "source": source_kind, "params_hash": est.params_hash,
        "roi": list(roi or ()), "measured_distance_m": m.distance_m, "sigma_m": m.sigma_m,
        "quality": m.quality, "bbox": list(m.bbox) if m.bbox else None, "reason": m.reason,
        "timings_ms": {k: round(v, 2) for k, v in est.timings_ms.items()},
    }
    if frame.truth_m is not None:
        meta["branch_distance_m"] = frame.truth_m
    meta.update({k: v for k, v in frame.meta.items() if k not in meta})
    return meta


def ensure_log_dir(path: Path) -> Path:
    """Create ``path`` if needed and prove this user can write in it; ConfigError (one line) if not."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".uav-depth-write-test.", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ConfigError("logging.dir", f"must be a directory this user (uid {os.getuid()}) can create and "
                          f"write ({exc.strerror or exc}); set logging.dir: null to fly without logging",
                          str(path)) from exc
    return path


def free_mb(path: Path) -> float:
    """Free space for this user on the file system holding ``path``, MB."""
    return shutil.disk_usage(path).free / (1024 * 1024)


def tree_size(path: Path) -> int:
    """Bytes in the files under ``path`` (0 when it does not exist)."""
    total = 0
    try:
        entries = list(os.scandir(path))
    except OSError:   # missing, not a directory, unreadable: nothing of ours to count
        return 0
    for entry in entries:
        try:
            if entry.is_dir(follow_symlinks=False):
                total += tree_size(Path(entry.path))
            else:
                total += entry.stat(follow_symlinks=False).st_size
        except OSError:
            continue
    return total


@dataclass(frozen=True)
class _Item:
    index: int
    left: np.ndarray
    right: np.ndarray
    reference: np.ndarray | None
    reference_source: Mapping[str, Any] | None
    meta: Mapping[str, Any]


class FrameLogger:
    """See the module docstring. ``on_stop(reason)`` is called once when logging stops on its own."""

    def __init__(self, config: LoggingConfig, calibration: Calibration, source_kind: str,
                 on_stop: Callable[[str], None] | None = None):
        if config.dir is None:
            raise ValueError("FrameLogger needs logging.dir")
        self.config = config
        self.calibration = calibration
        self.source_kind = source_kind
        self.on_stop = on_stop
        self.root = Path(config.dir)
        self.budget = int(config.max_mb * 1024 * 1024)
        self._queue: queue.Queue[_Item | None] = queue.Queue(maxsize=config.queue_frames)
        self._seen = 0
        self._demand = threading.Event()
        self._thread: threading.Thread | None = None
        self.session: Session | None = None
        self._writer: SessionWriter | None = None
        self._usage = 0
        self._frame_bytes = 0
        self.written = 0
        self.dropped = 0
        self.stopped: str | None = None
        self.t0 = time.monotonic()

    def start(self) -> "FrameLogger":
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            self._stop(f"cannot create log directory {self.root}: {exc.strerror or exc}")
            return self
        self._usage = tree_size(self.root)
        self._thread = threading.Thread(target=self._loop, name="frame-logger", daemon=True)
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        """The writer runs, or never started because logging stopped first (it runs on after a stop)."""
        return self._thread.is_alive() if self._thread is not None else self.stopped is not None

    def request(self) -> None:
        """Log the next processed frame whatever ``every_n`` says (on demand)."""
        self._demand.set()

    def consider(self, index: int, left: np.ndarray, right: np.ndarray, meta: Mapping[str, Any],
                 reference: np.ndarray | None = None, reference_source: Mapping[str, Any] | None = None) -> bool:
        """Called for every processed frame; queues it when it is due. Never blocks."""
        if self.stopped is not None or self._thread is None:
            return False
        self._seen += 1
        n = self.config.every_n
        due = (n > 0 and (self._seen - 1) % n == 0) or self._demand.is_set()
        if not due:
            return False
        self._demand.clear()
        try:
            self._queue.put_nowait(_Item(index, left, right, reference, reference_source, dict(meta)))
            return True
        except queue.Full:
            self.dropped += 1
            return False

    def close(self, timeout_s: float) -> int:
        """Finish queued frames within ``timeout_s``; returns how many were abandoned."""
        if self._thread is None:
            return 0
        deadline = time.monotonic() + timeout_s
        while True:   # the sentinel must get in even if the queue is full
            try:
                self._queue.put(None, timeout=max(0.01, deadline - time.monotonic()))
                break
            except queue.Full:
                if time.monotonic() >= deadline:
                    break
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            return self._queue.qsize() + 1   # the frame being written and those still queued
        return 0

    # writer thread
    def _stop(self, reason: str) -> None:
        if self.stopped is None:
            self.stopped = reason
            log.warning("frame logging stopped: %s; the daemon keeps running", reason)
            if self.on_stop is not None:
                try:
                    self.on_stop(reason)
                except Exception:   # a failing notifier must not kill the writer
                    log.exception("frame logging: stop callback failed")

    def _new_session(self) -> SessionWriter:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = self.root / f"{stamp}-{self.source_kind}"
        k = 1
        while path.exists():
            path = self.root / f"{stamp}-{self.source_kind}-{k}"
            k += 1
        writer = SessionWriter(path, self.calibration)
        self.session = writer.session
        self._usage += tree_size(path)
        log.info("logging frames to %s (every %d frames, budget %.0f MB)", path, self.config.every_n,
                 self.config.max_mb)
        return writer

    def _make_room(self, needed: int) -> bool:
        if self._usage + needed <= self.budget:
            return True
        current = self.session.path.resolve() if self.session else None
        others = sorted(p for p in self.root.iterdir()
                        if p.is_dir() and p.resolve() != current and Session.is_session(p))
        for old in others:
            size = tree_size(old)
            shutil.rmtree(old, ignore_errors=True)
            self._usage -= size
            log.info("disk budget: removed the oldest session %s (%.1f MB)", old, size / 1e6)
            if self._usage + needed <= self.budget:
                return True
        self._usage = tree_size(self.root)   # resynchronise before giving up
        return self._usage + needed <= self.budget

    def _loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None or self.stopped is not None:
                if item is None:
                    return
                continue
            try:
                if self._writer is None:
                    self._writer = self._new_session()
                guess = self._frame_bytes or (item.left.nbytes + item.right.nbytes +
                                              (item.reference.nbytes if item.reference is not None else 0))
                if not self._make_room(guess):
                    self._stop(f"disk budget of {self.config.max_mb:g} MB for {self.root} is used up by the "
                               "current session")
                    continue
                left_mb = free_mb(self.root) - guess / (1024 * 1024)
                if left_mb < self.config.min_free_mb:
                    self._stop(f"free space on {self.root}'s file system would fall to {max(left_mb, 0):.0f} MB, "
                               f"below logging.min_free_mb {self.config.min_free_mb:g} MB")
                    continue
                frame = self._writer.write(item.index, item.left, item.right, reference=item.reference,
                                           meta=dict(item.meta), reference_source=item.reference_source)
                size = sum(p.stat().st_size for p in frame.session.frames_dir.glob(f"{frame.frame_id}_*"))
                self._frame_bytes = size
                self._usage += size
                self.written += 1
            except OSError as exc:   # ENOSPC, EROFS, EDQUOT, EFBIG: stop logging, keep flying
                self._stop(f"cannot write to {self.root}: {exc.strerror or exc}")
            except Exception as exc:   # an encoder failure is the same story
                self._stop(f"cannot write a frame: {type(exc).__name__}: {exc}")
