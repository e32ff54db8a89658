"""The flight controller's side of the daemon tests: a real pymavlink udpin endpoint on loopback."""

from __future__ import annotations

import socket
import threading
import time

from uav_depth.daemon.mavlink_out import mavutil


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Receiver:
    """A real udpin endpoint recording (arrival time, message) on a thread."""

    def __init__(self):
        self.port = free_port()
        self.conn = mavutil().mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=255)
        self.msgs = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _loop(self):
        while not self._stop.is_set():
            m = self.conn.recv_match(blocking=True, timeout=0.05)
            if m is not None and m.get_type() != "BAD_DATA":
                self.msgs.append((time.monotonic(), m))

    def timed(self, mtype, since=0.0):
        """(arrival, message) of one type that arrived at or after ``since`` (monotonic)."""
        return [(t, m) for t, m in self.msgs if m.get_type() == mtype and t >= since]

    def of(self, mtype, since=0.0):
        return [m for _, m in self.timed(mtype, since)]

    def texts(self):
        return [m.text for m in self.of("STATUSTEXT")]

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
