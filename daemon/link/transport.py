"""The byte pipes under the MAVLink link: the interface, UDP out and in, and opening a pipe by its URL.

No MAVLink in here. pymavlink's own connection objects are not used for I/O because
they do what a flying link must not: ``udpin`` answers every address that ever sent
it a byte (and remembers each forever), ``udpout`` binds to 0.0.0.0, a TCP write may
block or go out half-written, and reconnects sleep. Each transport here is owned by
one thread (the link's I/O thread), never blocks, and writes a frame whole or not at
all:

- :class:`UdpOut`: bound to ``bind_address`` (or the address the route to the
  peer uses: 127.0.0.1 for a loopback peer) and ``connect()``-ed, so the kernel
  delivers datagrams from the peer only.
- :class:`UdpIn`: bound to HOST:PORT (exclusively: a port another program holds is
  an error, not a shared stream); it talks to one peer, the address the link
  :meth:`~UdpIn.bind_peer` s (see :mod:`.peers`), and drops datagrams from every
  other address unread unless the link asks to hear them (``hear_strangers``).
- the streams (TCP client and server, serial) live in :mod:`.streams`; :mod:`.urls` opens a
  pipe from ``mavlink.url``.
"""

from __future__ import annotations

import socket
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
#: Kernel receive buffer for UDP sockets: a flood overflows it (the kernel drops), it does not grow memory.
UDP_RCVBUF = 64 * 1024


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

    def write(self, buf: bytes, deadline: float | None = None, now: float | None = None) -> bool:
        """Send one frame now, whole, or return False (nothing sent). Raises ConnectionError when gone.

        ``deadline`` (monotonic s): streams remember it while the kernel holds the frame;
        ``now`` (monotonic s): nothing past its deadline is written, a frame's tail included.
        """
        raise NotImplementedError

    @property
    def can_send(self) -> bool:
        return True

    def close(self) -> None:
        raise NotImplementedError

    def poll(self) -> None:
        """Housekeeping on every I/O loop turn (accept a new TCP peer...)."""


def split_url(url: str) -> tuple[str, int]:
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

    def write(self, buf: bytes, deadline: float | None = None, now: float | None = None) -> bool:
        try:
            return self.sock.send(buf) == len(buf)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return False

    def close(self) -> None:
        self.sock.close()


class UdpIn(Transport):
    """Listens on HOST:PORT; reads and writes one peer, ``peer`` (None: nobody yet, nothing is sent)."""

    def __init__(self, host: str, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF)
        self.sock.bind((host, port))     # no SO_REUSEADDR: a port another program holds fails here
        self.sock.setblocking(False)
        self.peer: tuple[str, int] | None = None
        self.peer_heard = 0.0
        #: Read datagrams from other addresses too (returned with their address; the link decides).
        self.hear_strangers = True
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
            stranger = self.peer is not None and addr != self.peer
            if (len(data) > MAX_DATAGRAM or not data or data[0] not in MAVLINK_MAGIC
                    or (stranger and not self.hear_strangers)):
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

    def write(self, buf: bytes, deadline: float | None = None, now: float | None = None) -> bool:
        if self.peer is None:
            return False
        try:
            return self.sock.sendto(buf, self.peer) == len(buf)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return False

    def close(self) -> None:
        self.sock.close()
