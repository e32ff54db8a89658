"""Files written so that a reader never sees half of one."""

from __future__ import annotations

import os
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


def read_text_file(path: str | os.PathLike[str], what: str) -> str:
    """The UTF-8 text of ``path``; every way it cannot be read is one FileFormatError naming ``what``.

    ``what``: what the file should be ("parameter file", "config", ...). Missing,
    a directory, no permission, not UTF-8 or binary (NUL bytes): the message says
    which, with the byte offset where the text is broken.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError as exc:
        raise FileFormatError(f"{path}: {what} not found") from exc
    except IsADirectoryError as exc:
        raise FileFormatError(f"{path}: {what} is a directory, not a file") from exc
    except PermissionError as exc:
        raise FileFormatError(f"{path}: cannot read {what}: permission denied for this user "
                              f"(uid {os.getuid()})") from exc
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read {what} ({exc.strerror or exc})") from exc
    nul = raw.find(b"\0")
    if nul >= 0:
        raise FileFormatError(f"{path}: {what} is a binary file, not text (NUL byte at offset {nul})")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise FileFormatError(f"{path}: {what} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                              f"{exc.start}, line {line})") from exc
