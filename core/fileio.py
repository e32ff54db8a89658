"""Files written so that a reader never sees half of one, and read no further than a bound."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from uav_depth.core.errors import FileFormatError


def _umask() -> int:
    """The process umask, read without setting it (os.umask would change it for every thread a moment)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    return 0o022


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Replace ``path`` with ``text`` atomically (same-directory temp, fsync, rename).

    An existing file keeps its owner, group and mode (a ``sudo`` run must not leave the
    daemon's parameter file as root's 0600, which the service could no longer read); where
    the writer may not give the file back to its owner, the owner becomes the writer but the
    mode is still kept. A new file gets 0666 minus the umask, as ``open()`` would give it.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        old = os.stat(path)
    except FileNotFoundError:
        old = None
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        if old is None:
            os.fchmod(fd, 0o666 & ~_umask())
        else:
            try:
                os.fchown(fd, old.st_uid, old.st_gid)
            except PermissionError:
                pass
            os.fchmod(fd, old.st_mode & 0o7777)
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    try:
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:  # some filesystems cannot fsync a directory; the rename is still atomic
        pass
    return path


#: The most a text file the project reads may hold unless its reader says otherwise (frame metadata, ...).
MAX_TEXT_BYTES = 1 << 20


def _kib(n: int) -> str:
    return f"{n // 1024} KiB" if n >= 1024 else f"{n} bytes"


def read_bounded(path: str | os.PathLike[str], what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them; else one FileFormatError.

    Bounded whatever the path names: a FIFO or a device (``/dev/zero``) is refused before a byte is
    read (opening does not wait for a writer), a file over ``max_bytes`` is refused by its size, and
    a file that grows while it is read is read no further than the bound.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError as exc:
        raise FileFormatError(f"{path}: {what} not found") from exc
    except PermissionError as exc:
        raise FileFormatError(f"{path}: cannot read {what}: permission denied for this user "
                              f"(uid {os.getuid()})") from exc
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read {what} ({exc.strerror or exc})") from exc
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise FileFormatError(f"{path}: {what} is a directory, not a file")
        if not stat.S_ISREG(st.st_mode):
            raise FileFormatError(f"{path}: {what} is not a regular file (a device, FIFO or socket)")
        if st.st_size > max_bytes:
            raise FileFormatError(f"{path}: {what} is {st.st_size} bytes, more than the {_kib(max_bytes)} "
                                  f"a {what} may have")
        chunks, left = [], max_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 16))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read {what} ({exc.strerror or exc})") from exc
    finally:
        os.close(fd)
    raw = b"".join(chunks)
    if len(raw) > max_bytes:
        raise FileFormatError(f"{path}: {what} grew past the {_kib(max_bytes)} a {what} may have while it was read")
    return raw


def read_text_file(path: str | os.PathLike[str], what: str, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of ``path``; every way it cannot be read is one FileFormatError naming ``what``.

    ``what``: what the file should be ("parameter file", "config", ...). Missing,
    a directory, not a regular file, larger than ``max_bytes``, no permission, not UTF-8
    or binary (NUL bytes): the message says which, with the byte offset where the text is broken.
    """
    path = Path(path)
    raw = read_bounded(path, what, max_bytes)
    nul = raw.find(b"\0")
    if nul >= 0:
        raise FileFormatError(f"{path}: {what} is a binary file, not text (NUL byte at offset {nul})")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise FileFormatError(f"{path}: {what} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                              f"{exc.start}, line {line})") from exc
