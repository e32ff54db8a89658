"""A real unix datagram socket standing in for systemd's NOTIFY_SOCKET, for the tests that read what the daemon
tells systemd (READY, WATCHDOG, STATUS)."""

import socket
import threading
import time


class NotifySocket:
    """(arrival, datagram) pairs as systemd would receive them."""

    def __init__(self, path):
        self.path = str(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.settimeout(0.1)
        self.datagrams = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _loop(self):
        while not self._stop.is_set():
            try:
                self.datagrams.append((time.monotonic(), self.sock.recv(4096).decode()))
            except socket.timeout:
                continue

    def lines(self):
        return [line for _, d in self.datagrams for line in d.split("\n")]

    def close(self):
        self._stop.set()
        self._t.join(1)
        self.sock.close()
