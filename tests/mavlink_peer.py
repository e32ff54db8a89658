"""The flight controller's side of the daemon tests: a real pymavlink udpin endpoint on loopback."""

from __future__ import annotations

import socket
import threading
import time

from uav_depth.daemon.link.vocabulary import mavutil


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Receiver:
    """A real pymavlink endpoint recording (arrival time, message) on a thread.

    Without ``url``: ``udpin`` on a free loopback port (``self.port``), the flight controller's side
    of the daemon's ``udpout``. ``autopilot=True``: it behaves as ArduPilot and PX4 do on a link:
    a HEARTBEAT (quadrotor, ArduPilot) every second and an answer to every TIMESYNC request.
    :meth:`pause` stops it as SIGSTOP would (nothing read, nothing sent) until :meth:`resume`.
    """

    def __init__(self, url: str | None = None, sysid: int = 255, compid: int = 0, autopilot: bool = False):
        if url is None:
            self.port = free_port()
            url = f"udpin:127.0.0.1:{self.port}"
        self.conn = mavutil().mavlink_connection(url, source_system=sysid, source_component=compid)
        self.autopilot = autopilot
        self.msgs = []
        self.paused = threading.Event()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def pause(self):
        self.paused.set()

    def resume(self):
        self.paused.clear()

    def _loop(self):
        next_hb = 0.0
        while not self._stop.is_set():
            if self.paused.is_set():
                time.sleep(0.005)
                continue
            now = time.monotonic()
            try:
                if self.autopilot and now >= next_hb:
                    self.conn.mav.heartbeat_send(2, 3, 0, 0, 4)       # quadrotor, ArduPilot, active
                    next_hb = now + 1.0
                m = self.conn.recv_match(blocking=True, timeout=0.02)
            except OSError:     # the peer closed a TCP connection under us
                return
            if m is None or m.get_type() == "BAD_DATA":
                continue
            self.msgs.append((time.monotonic(), m))
            if self.autopilot and m.get_type() == "TIMESYNC" and m.tc1 == 0:
                self.conn.mav.timesync_send(time.monotonic_ns(), m.ts1)   # as GCS_MAVLINK::handle_timesync

    def timed(self, mtype, since=0.0):
        """(arrival, message) of one type that arrived at or after ``since`` (monotonic)."""
        return [(t, m) for t, m in self.msgs if m.get_type() == mtype and t >= since]

    def of(self, mtype, since=0.0):
        return [m for _, m in self.timed(mtype, since)]

    def texts(self):
        return [m.text for m in self.of("STATUSTEXT")]

    def wait_for(self, mtype, timeout=5.0, count=1, pred=lambda m: True):
        """At least ``count`` messages of ``mtype`` satisfying ``pred``, or AssertionError after ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hits = [m for m in self.of(mtype) if pred(m)]
            if len(hits) >= count:
                return hits
            time.sleep(0.01)
        raise AssertionError(f"{count} x {mtype} not received within {timeout} s (got {len(self.of(mtype))})")

    def wait(self, pred, timeout=10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pred():
                return True
            time.sleep(0.02)
        return False

    def close(self):
        self._stop.set()
        self._t.join(1)
        self.conn.close()
