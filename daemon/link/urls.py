"""``mavlink.url`` -> the pipe: open it for the link, or try it for ``run --check``."""

from __future__ import annotations

import errno
import socket

from uav_depth.daemon.link.streams import Serial, TcpClient, TcpServer
from uav_depth.daemon.link.transport import Transport, UdpIn, UdpOut, split_url


def open_transport(url: str, baud: int, bind_address: str | None = None) -> Transport:
    """The transport for a pymavlink-style connection string (see ``mavlink.url``).

    Raises OSError, ValueError or ConnectionError when it cannot be opened now (the
    link retries every 0.25 s at most).
    """
    if url.startswith("/dev/") or url.upper().startswith("COM"):
        return Serial(url, baud)
    scheme, _, rest = url.partition(":")
    host, port = split_url(rest)
    if scheme == "udpout":
        return UdpOut(host, port, bind_address)
    if scheme in ("udpin", "udp"):
        return UdpIn(host, port)
    if scheme == "tcp":
        return TcpClient(host, port)
    if scheme == "tcpin":
        return TcpServer(host, port)
    raise ValueError(f"unknown connection scheme {scheme!r}")


def try_open(url: str, baud: int, bind_address: str | None = None) -> tuple[str | None, str | None]:
    """Open the link's pipe once and close it: (problem, note), each None or one line.

    ``problem``: the link cannot be opened as configured (a missing serial device, a
    port another program holds, an address this machine does not have, a host name that
    does not resolve): ``run`` would retry for ever and send nothing. ``note``: what
    could not be checked (a TCP autopilot is not connected to: it may not be up yet).
    """
    scheme, _, rest = url.partition(":")
    try:
        if scheme == "tcp":    # not connected to: a connection starts SITL's clock, and the autopilot may be down
            socket.getaddrinfo(*split_url(rest), socket.AF_INET, socket.SOCK_STREAM)
            return None, f"{url} is not tried now (run connects once the autopilot listens)"
        t = open_transport(url, baud, bind_address)
    except (OSError, ValueError, ConnectionError) as exc:
        return _why(url, exc), None
    t.close()
    return None, None


def _why(url: str, exc: BaseException) -> str:
    err = getattr(exc, "errno", None)
    cause = exc.__cause__ if isinstance(exc, ConnectionError) and exc.__cause__ is not None else exc
    err = err if err is not None else getattr(cause, "errno", None)
    if err == errno.EADDRINUSE or "busy" in str(exc).lower() or "lock" in str(exc).lower():
        what = "is in use by another program (another uav-depth, MAVProxy?)"
    elif err == errno.ENOENT or "no such file" in str(exc).lower():
        what = "does not exist (is the flight controller connected?)"
    elif err == errno.EADDRNOTAVAIL:
        what = "names an address this machine does not have"
    else:
        what = f"cannot be opened ({type(exc).__name__}: {exc})"
    return f"mavlink.url {url} {what}"
