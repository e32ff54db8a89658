"""Watch one file for changes: inotify when the kernel has it, polling always as the fallback.

The tuner replaces the parameter file atomically (temp file + rename), so the
watch is on the *directory* (a rename replaces the inode a file watch would
follow). Every ``poll_s`` the file's identity (inode, size, mtime) is compared
anyway, which covers file systems without inotify and missed events. The watcher
runs until its stop event is set; ``on_change`` runs on the watcher's thread.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import logging
import os
import select
import struct
import threading
import time
from pathlib import Path
from typing import Callable

log = logging.getLogger("uav_depth.reload")

# <sys/inotify.h>
_IN_MODIFY, _IN_ATTRIB, _IN_CLOSE_WRITE = 0x002, 0x004, 0x008
_IN_MOVED_FROM, _IN_MOVED_TO, _IN_CREATE, _IN_DELETE = 0x040, 0x080, 0x100, 0x200
_IN_NONBLOCK, _IN_CLOEXEC = 0o4000, 0o2000000
_EVENT = struct.Struct("iIII")   # wd, mask, cookie, len
#: Quiet time after an event before the file is read: editors write in several steps.
SETTLE_S = 0.05
_SLICE_S = 0.25
#: A changed file is read only once it has kept the same (inode, size, mtime) for this long
#: and no process holds it open for writing (see :func:`wait_until_complete`).
STABLE_S = 0.3


def file_signature(path: Path) -> tuple[int, int, int] | None:
    """(inode, size, mtime ns) of ``path``, or None when it does not exist."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def open_for_writing(path: Path) -> bool | None:
    """True when some process holds ``path`` open for writing, False when none does, None when unknown.

    Linux refuses a read lease (F_SETLEASE F_RDLCK) on a file that is open for
    writing anywhere: taking one and dropping it at once is a cheap probe. Only the
    file's owner (or CAP_LEASE) may take a lease; otherwise the answer is None.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.fcntl(fd, fcntl.F_SETLEASE, fcntl.F_RDLCK)
        fcntl.fcntl(fd, fcntl.F_SETLEASE, fcntl.F_UNLCK)
        return False
    except OSError as exc:
        return True if exc.errno in (errno.EAGAIN, errno.EBUSY) else None
    finally:
        os.close(fd)


def wait_until_complete(path: Path, stop: threading.Event, stable_s: float = STABLE_S,
                        timeout_s: float | None = None) -> bool:
    """Wait until ``path`` is complete: unchanged for ``stable_s`` and open for writing nowhere.

    A writer that keeps the file open (``>`` redirection, an editor writing in
    parts) is waited for, however slow; a writer that closes a half file and
    reopens it later cannot be told from a finished one (write atomically:
    temp file + rename, as ``uav-depth tune`` does). Returns False when ``stop``
    is set or ``timeout_s`` passes first; True also when the file is gone.
    """
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    told = False
    while True:
        before = file_signature(path)
        if stop.wait(stable_s):
            return False
        now = file_signature(path)
        if now is None:
            return True
        if now == before and open_for_writing(path) is not True:
            return True
        if not told:
            log.info("%s is being written; waiting until it is complete", path)
            told = True
        if deadline is not None and time.monotonic() > deadline:
            return False


class _Inotify:
    """A minimal inotify watch on one directory through libc (no native dependency)."""

    def __init__(self, directory: Path):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        self.fd = libc.inotify_init1(_IN_NONBLOCK | _IN_CLOEXEC)
        if self.fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1 failed")
        mask = _IN_MODIFY | _IN_ATTRIB | _IN_CLOSE_WRITE | _IN_MOVED_FROM | _IN_MOVED_TO | _IN_CREATE | _IN_DELETE
        if libc.inotify_add_watch(self.fd, os.fsencode(str(directory)), mask) < 0:
            err = ctypes.get_errno()
            os.close(self.fd)
            raise OSError(err, f"inotify_add_watch {directory} failed")

    def wait(self, name: str, timeout_s: float) -> bool:
        """True when an event about ``name`` arrived within ``timeout_s``."""
        readable, _, _ = select.select([self.fd], [], [], timeout_s)
        if not readable:
            return False
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return False
        hit, i = False, 0
        while i + _EVENT.size <= len(data):
            _, _, _, length = _EVENT.unpack_from(data, i)
            raw = data[i + _EVENT.size:i + _EVENT.size + length].rstrip(b"\0")
            hit |= os.fsdecode(raw) == name
            i += _EVENT.size + length
        return hit

    def close(self) -> None:
        os.close(self.fd)


class FileWatcher:
    """Calls ``on_change(path)`` when ``path`` is created, replaced, modified or removed.

    ``poll_s``: the polling period (and the longest wait for a missed event);
    ``use_inotify``: False forces pure polling; ``since``: the :func:`file_signature`
    the caller last read (default: the file as it is when the watch starts), so a
    change between the caller's read and the start of the watch is not missed.
    """

    _UNSET = object()

    def __init__(self, path: str | os.PathLike[str], on_change: Callable[[Path], None], poll_s: float = 1.0,
                 use_inotify: bool = True, since: object = _UNSET):
        self.path = Path(path)
        self.on_change = on_change
        self.poll_s = poll_s
        self.use_inotify = use_inotify
        self.mode = "poll"
        self._thread: threading.Thread | None = None
        self._stop: threading.Event | None = None
        self._watching = threading.Event()
        self._poked = threading.Event()
        self._since = since

    def poke(self) -> None:
        """Handle the file now, changed or not (SIGHUP): on the watcher's thread, within a slice."""
        self._poked.set()

    def run(self, stop: threading.Event) -> None:
        """Watch until ``stop`` is set (blocking; :meth:`start` runs it on a thread)."""
        notify = None
        if self.use_inotify and self.path.parent.is_dir():
            try:
                notify = _Inotify(self.path.parent)
                self.mode = "inotify"
            except (OSError, AttributeError) as exc:   # no inotify (not Linux, limits reached): poll
                log.info("watching %s by polling every %.2g s (%s)", self.path, self.poll_s, exc)
        seen = file_signature(self.path) if self._since is FileWatcher._UNSET else self._since
        next_poll = time.monotonic() + self.poll_s
        self._watching.set()
        try:
            while not stop.is_set():
                # short slices, so a set stop event ends the watch within a quarter second
                slice_s = max(0.0, min(_SLICE_S, next_poll - time.monotonic()))
                hit = notify.wait(self.path.name, slice_s) if notify is not None else False
                if notify is None and stop.wait(slice_s):
                    break
                if hit and stop.wait(SETTLE_S):
                    break
                poked = self._poked.is_set()
                if not hit and not poked and time.monotonic() < next_poll:
                    continue
                self._poked.clear()
                next_poll = time.monotonic() + self.poll_s
                now = file_signature(self.path)
                if now != seen or poked:
                    seen = now
                    try:
                        self.on_change(self.path)
                    except Exception:   # a failing handler must not end the watch
                        log.exception("handling a change of %s failed", self.path)
        finally:
            if notify is not None:
                notify.close()

    def start(self, stop: threading.Event) -> "FileWatcher":
        """Watch on a thread; returns once the file's current state is recorded (later changes are seen)."""
        self._stop = stop
        self._thread = threading.Thread(target=self.run, args=(stop,), name="params-watch", daemon=True)
        self._thread.start()
        self._watching.wait(2.0)
        return self

    @property
    def alive(self) -> bool:
        """The watch runs (it ends only when its stop event is set, or by dying)."""
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout_s: float) -> bool:
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True
