"""``mavlink.url`` -> the pipe the link opens."""

from __future__ import annotations

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
