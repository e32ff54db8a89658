"""The stream pipes under the MAVLink link: TCP client, TCP server, serial.

A stream may take only part of a frame: the rest (the tail) is finished before
anything else, and only while the frame is within its deadline; a tail past its
deadline is never written (the pipe is discarded instead, and the peer's parser
drops the cut frame). Every frame handed to the kernel is remembered with its
deadline until the kernel no longer holds any of its bytes: :meth:`Stream.overdue`
says when one still held (unsent, or sent and not acknowledged) has passed its
deadline, so the link can :meth:`~Stream.discard` it (a TCP reset, a tty output
flush) before it arrives old.
"""

from __future__ import annotations

import collections
import errno
import fcntl
import os
import socket
import struct
import termios

from uav_depth.daemon.link.transport import Transport

#: Bytes read from a stream per call.
STREAM_READ = 2048
#: Kernel send buffer for streams: small, so little can wait in it.
STREAM_SNDBUF = 8 * 1024


def _outq(fd: int) -> int:
    """Bytes the kernel still holds for sending (TCP: unsent + unacknowledged; tty: unsent)."""
    try:
        return struct.unpack("i", fcntl.ioctl(fd, termios.TIOCOUTQ, b"\0\0\0\0"))[0]
    except OSError:
        return 0


class Stream(Transport):
    """A byte stream: frames may be split by the kernel, so a tail is kept and finished first.

    Every frame handed to the kernel is remembered with its deadline (None: none) until
    the kernel no longer holds any of its bytes, so :meth:`overdue` can tell when a
    frame still waiting in the kernel (unsent, or sent but unacknowledged) has passed
    its deadline: then the link calls :meth:`discard`, and it never arrives.
    """

    stream = True

    def __init__(self) -> None:
        self._tail = b""
        self._tail_deadline: float | None = None
        self._written = 0                                   # bytes handed to the kernel on this pipe
        self._frames: collections.deque = collections.deque()   # (end offset, deadline) still in the kernel

    def _fd(self) -> int | None:
        raise NotImplementedError

    def _send(self, buf: bytes) -> int:
        raise NotImplementedError

    def _reset_state(self) -> None:
        self._tail, self._tail_deadline, self._written = b"", None, 0
        self._frames.clear()

    def _flush_tail(self, now: float | None) -> bool:
        """Finish the frame the kernel took only part of; False while it cannot (or must not: past its
        deadline, its end would complete an old reading at the peer)."""
        if self._tail and self.tail_expired(now):
            return False
        while self._tail:
            try:
                n = self._send(self._tail)
            except (BlockingIOError, InterruptedError):
                return False
            self._written += n
            self._tail = self._tail[n:]
        return True

    def tail_expired(self, now: float | None) -> bool:
        return bool(self._tail) and None not in (now, self._tail_deadline) and now > self._tail_deadline

    def write(self, buf: bytes, deadline: float | None = None, now: float | None = None) -> bool:
        if self._fd() is None or not self._flush_tail(now):
            return False
        try:
            n = self._send(buf)
        except (BlockingIOError, InterruptedError):
            return False
        self._written += n
        if n < len(buf):
            self._tail, self._tail_deadline = buf[n:], deadline   # its end goes before anything else
        self._frames.append((self._written + len(buf) - n, deadline))
        if len(self._frames) > 4096:
            self._frames.popleft()
        return True

    def queued_bytes(self) -> int:
        fd = self._fd()
        return len(self._tail) + (_outq(fd) if fd is not None else 0)

    def overdue(self, now: float) -> bool:
        """True when a frame the kernel still holds (unsent or unacknowledged) has passed its deadline."""
        fd = self._fd()
        if fd is None:
            return False
        if self.tail_expired(now):
            return True
        gone = self._written - _outq(fd)                    # bytes the peer has acknowledged
        while self._frames and self._frames[0][0] <= gone:
            self._frames.popleft()
        return any(d is not None and now > d for _, d in self._frames)

    def discard(self) -> None:
        """Throw away whatever has not gone out yet (it would arrive old)."""
        self._reset_state()


def _tune(sock: socket.socket) -> None:
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF)
    sock.setblocking(False)


def _reset(sock: socket.socket) -> None:
    """Close with RST: the kernel drops our unsent bytes instead of delivering them late."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    except OSError:
        pass
    sock.close()


class TcpClient(Stream):
    def __init__(self, host: str, port: int, connect_timeout_s: float = 0.5):
        super().__init__()
        self.sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        _tune(self.sock)
        self.description = f"tcp {host}:{port}"

    def _fd(self) -> int | None:
        return self.sock.fileno()

    def fileno(self) -> int:
        return self.sock.fileno()

    def _send(self, buf: bytes) -> int:
        try:
            return self.sock.send(buf)
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise ConnectionError(f"peer closed the TCP connection ({exc.strerror})") from exc

    def read(self) -> list[tuple[bytes, object]]:
        try:
            data = self.sock.recv(STREAM_READ)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError as exc:
            raise ConnectionError(f"TCP connection lost ({exc.strerror})") from exc
        if not data:
            raise ConnectionError("peer closed the TCP connection")
        return [(data, None)]

    def discard(self) -> None:
        super().discard()
        self.close()
        self.dead = True      # the bytes held would arrive old: reset, and let the link reconnect

    def close(self) -> None:
        if self.sock.fileno() >= 0:
            _reset(self.sock)


class TcpServer(Stream):
    """Listens on HOST:PORT; one peer at a time, the newest connection wins."""

    def __init__(self, host: str, port: int):
        super().__init__()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(4)
        self.listener.setblocking(False)
        self.conn: socket.socket | None = None
        self.accepted = 0
        self.description = f"tcpin {host}:{port}"

    def fileno(self) -> int:
        return self.conn.fileno() if self.conn is not None else self.listener.fileno()

    def _fd(self) -> int | None:
        return self.conn.fileno() if self.conn is not None else None

    @property
    def can_send(self) -> bool:
        return self.conn is not None

    def poll(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            _tune(conn)
            if self.conn is not None:    # the peer came back on a new connection: the old one is dead
                _reset(self.conn)
            self.conn = conn
            self.accepted += 1
            self._reset_state()

    def new_connection(self) -> bool:
        """True once per accepted connection (the link resets its per-connection state)."""
        seen = getattr(self, "_seen", 0)
        self._seen = self.accepted
        return self.accepted != seen

    def _drop(self) -> None:
        if self.conn is not None:
            _reset(self.conn)
        self.conn = None
        self._reset_state()

    def _send(self, buf: bytes) -> int:
        assert self.conn is not None
        try:
            return self.conn.send(buf)
        except (BrokenPipeError, ConnectionResetError):
            self._drop()
            return len(buf)               # gone: nothing more to do with this frame

    def read(self) -> list[tuple[bytes, object]]:
        if self.conn is None:
            return []
        try:
            data = self.conn.recv(STREAM_READ)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            self._drop()
            return []
        if not data:
            self._drop()
            return []
        return [(data, None)]

    def discard(self) -> None:
        super().discard()
        self._drop()

    def close(self) -> None:
        self._drop()
        self.listener.close()


class Serial(Stream):
    def __init__(self, device: str, baud: int):
        super().__init__()
        import serial   # pyserial comes with pymavlink

        try:
            self.port = serial.Serial(device, baud, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, ValueError) as exc:
            raise ConnectionError(str(exc)) from exc
        os.set_blocking(self.port.fd, False)
        self.description = f"serial {device} at {baud} baud"

    def fileno(self) -> int:
        return self.port.fd

    def _fd(self) -> int | None:
        return self.port.fd

    def _send(self, buf: bytes) -> int:
        try:
            return os.write(self.port.fd, buf)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EINTR):
                raise BlockingIOError from exc
            raise ConnectionError(f"serial write failed ({exc.strerror})") from exc

    def read(self) -> list[tuple[bytes, object]]:
        try:
            data = os.read(self.port.fd, STREAM_READ)
        except BlockingIOError:
            return []
        except OSError as exc:
            raise ConnectionError(f"serial read failed ({exc.strerror})") from exc
        return [(data, None)] if data else []

    def discard(self) -> None:
        super().discard()
        try:
            termios.tcflush(self.port.fd, termios.TCOFLUSH)
        except termios.error:
            pass

    def close(self) -> None:
        self.port.close()
