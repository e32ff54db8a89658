"""Issue 13's link faults on udpin against the real daemon process (`uav-depth run`, synthetic source) and
bare UDP endpoints on loopback: udpin answers only its autopilot (item 4), is not taken over after the
autopilot falls silent, and with signing only a signed new heartbeat rebinds it.
"""

import socket
import time

from link_daemon import Daemon, wait_for
from mavlink_peer import Receiver, free_port


def test_udpin_answers_only_the_autopilot_it_bound_to(tmp_path):
    # item 4: a stranger sending one byte received 101 DISTANCE_SENSOR and 5 HEARTBEAT in 5 s
    port = free_port()
    daemon = Daemon(tmp_path, f"udpin:127.0.0.1:{port}")
    stranger = Receiver(f"udpout:127.0.0.1:{port}", sysid=42, compid=190)
    try:
        wait_for(lambda: "calibration:" in daemon.stderr(), 90, daemon, "start-up")
        stranger.conn.write(b"\x00")                                       # one byte
        stranger.conn.mav.heartbeat_send(6, 8, 0, 0, 4)                    # a ground station's HEARTBEAT
        time.sleep(1.0)
        autopilot = Receiver(f"udpout:127.0.0.1:{port}", sysid=1, compid=1, autopilot=True)
        try:
            wait_for(lambda: len(autopilot.of("DISTANCE_SENSOR")) >= 5, 60, daemon, "the autopilot's readings")
            for _ in range(3):                                             # a second "autopilot" turns up
                stranger.conn.mav.heartbeat_send(2, 3, 0, 0, 4)
                time.sleep(0.5)
            n = len(autopilot.of("DISTANCE_SENSOR"))
            time.sleep(1.0)
            assert len(autopilot.of("DISTANCE_SENSOR")) > n                # still served
        finally:
            autopilot.close()
        assert stranger.msgs == [], [m.get_type() for _, m in stranger.msgs][:10]
        assert "answering the autopilot at 127.0.0.1:" in daemon.stderr()
    finally:
        daemon.close()
        stranger.close()


class Udp:
    """A bare UDP endpoint on loopback: sends frames to the daemon's udpin port, collects what comes back."""

    def __init__(self, port):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.to = ("127.0.0.1", port)
        self.parser = _parser()
        self.got = []

    def send(self, frame: bytes):
        self.sock.sendto(frame, self.to)

    def flood(self, make, seconds: float, burst: int = 50) -> int:
        """Send a new ``make()`` frame ``burst`` at a time, 5 ms apart, for ``seconds``; how many were sent."""
        sent, end = 0, time.monotonic() + seconds
        while time.monotonic() < end:
            for _ in range(burst):
                self.send(make())
            sent += burst
            time.sleep(0.005)
        return sent

    def poll(self):
        while self.sock.fileno() >= 0:     # closed: what it got
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                break
            self.got += [m for m in self.parser.parse_buffer(data) or () if m.get_type() != "BAD_DATA"]
        return self.got

    def of(self, mtype):
        return [m for m in self.poll() if m.get_type() == mtype]

    def close(self):
        self.sock.close()


def _parser(key: bytes | None = None, sysid: int = 1, compid: int = 1):
    from uav_depth.daemon.link.vocabulary import mavutil

    mav = mavutil().mavlink.MAVLink(None, sysid, compid)
    mav.robust_parsing = True
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    return mav


def _heartbeat(mav) -> bytes:
    """An ArduPilot quadrotor's HEARTBEAT from ``mav`` (signed if it has a key): a fresh frame each call."""
    buf = mav.heartbeat_encode(2, 3, 0, 0, 4).pack(mav)
    mav.seq = (mav.seq + 1) % 256
    return buf


def _serve(port, frames, seconds, *peers):
    """Send ``frames()`` from the first peer every 0.1 s for ``seconds``, polling every peer."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if frames is not None:
            peers[0].send(frames())
        for p in peers:
            p.poll()
        time.sleep(0.1)


def test_udpin_is_not_taken_over_by_a_heartbeat_after_the_autopilot_falls_silent(tmp_path):
    # issue 44 item 5: after 3 s of autopilot silence any autopilot HEARTBEAT took the stream over
    # (140 readings to a stranger)
    port = free_port()
    daemon = Daemon(tmp_path, f"udpin:127.0.0.1:{port}")
    autopilot, stranger = Udp(port), Udp(port)
    mav = _parser()
    try:
        wait_for(lambda: "ready:" in daemon.stderr(), 90, daemon, "start-up")
        wait_for(lambda: (autopilot.send(_heartbeat(mav)), len(autopilot.of("DISTANCE_SENSOR")) >= 5)[1], 30,
                 daemon, "the autopilot's readings")
        time.sleep(3.5)                                    # the autopilot is silent
        _serve(port, lambda: _heartbeat(_parser()), 3.0, stranger, autopilot)    # a stranger says "autopilot"
        n = len(autopilot.of("DISTANCE_SENSOR"))
        _serve(port, lambda: _heartbeat(mav), 1.5, autopilot)                    # the autopilot is back
    finally:
        daemon.close()
        autopilot.close()
        stranger.close()
    assert stranger.got == [], f"the stranger got {len(stranger.got)} messages"
    assert len(autopilot.of("DISTANCE_SENSOR")) > n                              # still the owner's


def test_with_signing_a_replayed_heartbeat_takes_nothing_and_a_signed_new_one_rebinds(tmp_path):
    # issue 44 item 5: with signing on, each candidate was checked by a fresh parser with no memory of the
    # timestamps seen, so a replayed signed HEARTBEAT from a sender without the key got 55 readings
    key_file = tmp_path / "mavlink.key"
    key_file.write_text("correct horse battery staple\n")
    key_file.chmod(0o600)
    from uav_depth.daemon.link.signing import load_signing_key

    key = load_signing_key(key_file)
    port = free_port()
    daemon = Daemon(tmp_path, f"udpin:127.0.0.1:{port}", mavlink={"signing_key_file": str(key_file)})
    autopilot, attacker, moved = Udp(port), Udp(port), Udp(port)
    mav = _parser(key)
    captured = []
    try:
        wait_for(lambda: "ready:" in daemon.stderr(), 90, daemon, "start-up")
        wait_for(lambda: (captured.append(_heartbeat(mav)), autopilot.send(captured[-1]),
                          len(autopilot.of("DISTANCE_SENSOR")) >= 5)[2], 30, daemon, "the autopilot's readings")
        time.sleep(3.5)                                    # the autopilot is silent
        replays = iter(captured * 10)                      # every frame it sent, sent again by someone else
        _serve(port, lambda: next(replays), 3.0, attacker)
        _serve(port, lambda: _heartbeat(mav), 3.0, moved)   # the autopilot itself, with the key, on a new port
    finally:
        daemon.close()
        for p in (autopilot, attacker, moved):
            p.close()
    assert attacker.got == [], f"the replaying sender got {len(attacker.got)} messages"
    assert moved.of("DISTANCE_SENSOR"), daemon.stderr()[-2000:]                 # a signed HEARTBEAT re-binds
    assert "owns the stream now" in daemon.stderr()


def test_a_flood_of_wrongly_signed_datagrams_is_a_few_log_lines(tmp_path):
    # issue 44 item 5: before binding, each wrong-key datagram logged 2 lines: 5641 lines in 3 s
    key_file = tmp_path / "mavlink.key"
    key_file.write_text("correct horse battery staple\n")
    key_file.chmod(0o600)
    port = free_port()
    daemon = Daemon(tmp_path, f"udpin:127.0.0.1:{port}", mavlink={"signing_key_file": str(key_file)})
    flooder = Udp(port)
    wrong = _parser(b"\x01" * 32)
    try:
        wait_for(lambda: "ready:" in daemon.stderr(), 90, daemon, "start-up")
        time.sleep(1.0)
        before = daemon.stderr().count("\n")
        sent = flooder.flood(lambda: _heartbeat(wrong), 3.0)
        time.sleep(1.0)
        lines = daemon.stderr().count("\n") - before
        flood_lines = [line for line in daemon.stderr().splitlines()[before:] if "status:" not in line]
    finally:
        daemon.close()
        flooder.close()
    assert len(flood_lines) <= 5, f"{lines} lines for {sent} datagrams: {flood_lines[:8]}"
    assert flooder.got == []
