"""sd_notify over a real unix datagram socket."""

import os
import socket

import pytest

from uav_depth.daemon.notify import Notifier


@pytest.fixture
def listener(tmp_path):
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield path, sock
    sock.close()


def test_messages_arrive_on_a_real_socket(listener):
    path, sock = listener
    n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "10000000"})
    assert n.enabled and n.watchdog_s == 10.0
    assert n.ready("1.0 m, 20 fps")
    assert sock.recv(4096) == b"READY=1\nSTATUS=1.0 m, 20 fps"
    assert n.watchdog() and sock.recv(4096) == b"WATCHDOG=1"
    assert n.status("two\nlines") and sock.recv(4096) == b"STATUS=two lines"
    assert n.stopping() and sock.recv(4096) == b"STOPPING=1"


def test_abstract_namespace_socket():
    name = f"uav-depth-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        assert Notifier({"NOTIFY_SOCKET": "@" + name}).ready()
        assert sock.recv(4096) == b"READY=1"
    finally:
        sock.close()


def test_without_systemd_everything_is_a_no_op(tmp_path):
    n = Notifier({})
    assert not n.enabled and n.watchdog_s is None and not n.ready() and not n.watchdog()
    gone = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    assert not gone.ready()                    # a vanished socket is reported once, never raised


def test_watchdog_for_another_pid_is_not_ours():
    assert Notifier({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}).watchdog_s is None
    assert Notifier({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid())}).watchdog_s == 5.0
