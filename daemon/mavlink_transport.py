"""The byte pipes under the MAVLink link: UDP out/in, TCP client/server, serial. No MAVLink in here.

pymavlink's own connection objects are not used for I/O because they do what a
flying link must not: ``udpin`` answers every address that ever sent it a byte
(and remembers each forever), ``udpout`` binds to 0.0.0.0, a TCP write may block
or go out half-written, and reconnects sleep. Each transport here is owned by
one thread (the link's I/O thread), never blocks, and writes a frame whole or
not at all:

- :class:`UdpOut`: bound to ``bind_address`` (or the address the route to the
  peer uses: 127.0.0.1 for a loopback peer) and ``connect()``-ed, so the kernel
  delivers datagrams from the peer only.
- :class:`UdpIn`: bound to HOST:PORT; it talks to one peer, the address the link
  :meth:`~UdpIn.bind_peer` s (the autopilot's first HEARTBEAT), and drops
  datagrams from every other address unread.
- :class:`TcpClient` / :class:`TcpServer`: one stream; ``TcpServer`` keeps
  listening and a new connection replaces the old one (the peer came back).
- :class:`Serial`: a tty in non-blocking mode.

Stream transports (TCP, serial) keep a partly written frame's tail and finish it
before anything else; :meth:`Stream.overdue` says when a frame the kernel still
holds (unsent, or sent and not acknowledged) has passed its deadline, so the link
can discard it (:meth:`Stream.discard`: a TCP reset, a tty output flush) before it
arrives old.

Longer than 400 lines because each transport (udpin, udpout, tcp, tcpin, serial) keeps its non-blocking send and bounded read together.
"""

from __future__ import annotations

import collections
import errno
import fcntl
import os
import select
import socket
import struct
import termios
import time

#: Largest datagram worth parsing: MAVLink 2 frames are at most 280 bytes and an autopilot packs a
#: few per datagram at most; anything bigger is junk and is dropped unread (a 64 KB datagram costs
#: pymavlink's parser about 70 ms).
MAX_DATAGRAM = 4096
#: The first byte of every MAVLink frame (v2, v1). A MAVLink peer puts whole frames in a datagram, so a
#: datagram that starts with anything else is junk and is dropped unread (parsing junk costs CPU that
#: the stereo stage needs).
MAVLINK_MAGIC = (0xFD, 0xFE)
#: Datagrams read per call: the I/O thread writes between calls.
DATAGRAMS_PER_READ = 8
#: Bytes read per call, at most (a datagram is read whole): parsing 4 KB of junk takes pymavlink
#: about 5 ms, so a write never waits longer than that behind inbound traffic.
READ_BUDGET = 4096
#: Bytes read from a stream per call.
STREAM_READ = 2048
#: Kernel receive buffer for UDP sockets: a flood overflows it (the kernel drops), it does not grow memory.
UDP_RCVBUF = 64 * 1024
#: Kernel send buffer for streams: small, so little can wait in it.
STREAM_SNDBUF = 8 * 1024


class Transport:
    """One pipe. ``fileno()`` for select; ``read()`` -> list of (bytes, peer); ``write(buf)`` -> bool."""

    stream = False
    dead = False          # set when the pipe was torn down on purpose (the link reconnects)
    description = ""

    def fileno(self) -> int:
        raise NotImplementedError

    def read(self) -> list[tuple[bytes, object]]:
        """What is there now (never waits). Raises ConnectionError when the pipe is gone."""
        raise NotImplementedError

    def write(self, buf: bytes, deadline: float | None = None) -> bool:
        """Send one frame now, whole, or return False (nothing sent). Raises ConnectionError when gone.

        ``deadline`` (monotonic s): streams remember it while the kernel holds the frame.
        """
        raise NotImplementedError

    @property
    def can_send(self) -> bool:
        return True

    def close(self) -> None:
        raise NotImplementedError

    def poll(self) -> None:
        """Housekeeping on every I/O loop turn (accept a new TCP peer...)."""


def _split(url: str) -> tuple[str, int]:
    host, _, port = url.rpartition(":")
    return host, int(port)


class UdpOut(Transport):
    def __init__(self, host: str, port: int, bind_address: str | None = None):
        addr = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4]
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF)
        if bind_address:
            self.sock.bind((bind_address, 0))
        self.sock.connect(addr)           # binds to the route's source address; the kernel filters senders
        self.sock.setblocking(False)
        self.peer = addr
        self.local = self.sock.getsockname()
        self.description = f"udpout {addr[0]}:{addr[1]} from {self.local[0]}:{self.local[1]}"
        self.dropped_datagrams = 0

    def fileno(self) -> int:
        return self.sock.fileno()

    def read(self) -> list[tuple[bytes, object]]:
        out, budget = [], READ_BUDGET
        for _ in range(DATAGRAMS_PER_READ):
            if budget <= 0:
                break
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:     # ICMP: nobody listens there (yet)
                continue
            if len(data) > MAX_DATAGRAM or not data or data[0] not in MAVLINK_MAGIC:
                self.dropped_datagrams += 1
                continue
            out.append((data, self.peer))
            budget -= len(data)
        return out

    def write(self, buf: bytes, deadline: float | None = None) -> bool:
        try:
            return self.sock.send(buf) == len(buf)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return False

    def close(self) -> None:
        self.sock.close()


class UdpIn(Transport):
    def __init__(self, host: str, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.peer: tuple[str, int] | None = None
        self.peer_heard = 0.0
        self.description = f"udpin {host}:{port}"
        self.dropped_datagrams = 0

    def fileno(self) -> int:
        return self.sock.fileno()

    def bind_peer(self, addr: tuple[str, int]) -> None:
        self.peer = addr
        self.peer_heard = time.monotonic()

    def read(self) -> list[tuple[bytes, object]]:
        out, budget = [], READ_BUDGET
        for _ in range(DATAGRAMS_PER_READ):
            if budget <= 0:
                break
            try:
                data, addr = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:
                continue
            if (len(data) > MAX_DATAGRAM or not data or data[0] not in MAVLINK_MAGIC
                    or (self.peer is not None and addr != self.peer)):
                self.dropped_datagrams += 1      # junk, or a stranger: never parsed, never answered
                continue
            if addr == self.peer:
                self.peer_heard = time.monotonic()
            out.append((data, addr))
            budget -= len(data)
        return out

    @property
    def can_send(self) -> bool:
        return self.peer is not None

    def write(self, buf: bytes, deadline: float | None = None) -> bool:
        if self.peer is None:
            return False
        try:
            return self.sock.sendto(buf, self.peer) == len(buf)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return False

    def close(self) -> None:
        self.sock.close()


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

    def _flush_tail(self) -> bool:
        while self._tail:
            try:
                n = self._send(self._tail)
            except (BlockingIOError, InterruptedError):
                return False
            self._written += n
            self._tail = self._tail[n:]
        return True

    def write(self, buf: bytes, deadline: float | None = None) -> bool:
        if self._fd() is None or not self._flush_tail():
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
        if self._tail and self._tail_deadline is not None and now > self._tail_deadline:
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


def open_transport(url: str, baud: int, bind_address: str | None = None) -> Transport:
    """The transport for a pymavlink-style connection string (see ``mavlink.url``)."""
    if url.startswith("/dev/") or url.upper().startswith("COM"):
        return Serial(url, baud)
    scheme, _, rest = url.partition(":")
    host, port = _split(rest)
    if scheme == "udpout":
        return UdpOut(host, port, bind_address)
    if scheme in ("udpin", "udp"):
        return UdpIn(host, port)
    if scheme == "tcp":
        return TcpClient(host, port)
    if scheme == "tcpin":
        return TcpServer(host, port)
    raise ValueError(f"unknown connection scheme {scheme!r}")


def wait_readable(fds: list[int], timeout_s: float) -> list[int]:
    try:
        r, _, _ = select.select(fds, [], [], max(0.0, timeout_s))
    except (OSError, ValueError):
        return []
    return r
