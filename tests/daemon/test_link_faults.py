"""Issue 13's link faults against the real daemon process (`uav-depth run`, synthetic source) and a real
pymavlink peer on loopback: blind is never "far" (item 1), a stalled TCP peer never gets old distances as new
(item 2), inbound junk does not stall the stream (item 3), time_boot_ms is the capture time (item 8), and the
status line counts what reached an autopilot.

Ages are exact: time_boot_ms is the capture time on CLOCK_MONOTONIC, the clock this test reads too. The
assertions are about what arrived (truth), with generous time limits: the machine may be loaded.
"""

import re
import socket
import time

import pytest

from link_daemon import MAX_AGE_MS, Daemon, wait_for
from mavlink_peer import Receiver, free_port


def age_ms(t_arrival: float, msg) -> float:
    """Capture to arrival, ms (time_boot_ms is CLOCK_MONOTONIC ms, modulo 2^32)."""
    return (int(t_arrival * 1000) - msg.time_boot_ms) % 2 ** 32


def gaps(times):
    return [b - a for a, b in zip(times, times[1:])]


@pytest.fixture
def peer():
    r = Receiver(autopilot=True)
    yield r
    r.close()


def test_blind_sends_nothing_and_every_reading_is_inside_min_max(tmp_path, peer):
    # item 1: a stale estimate was sent as max + 1 ("clear" to PX4); now a blind daemon sends no
    # DISTANCE_SENSOR at all while its HEARTBEAT and STATUSTEXT say why
    daemon = Daemon(tmp_path, f"udpout:127.0.0.1:{peer.port}", ranging={"max_age_ms": 1})
    try:
        wait_for(lambda: "calibration:" in daemon.stderr(), 90, daemon, "start-up")
        wait_for(lambda: len(peer.of("HEARTBEAT")) >= 4, 30, daemon, "4 heartbeats")
        assert peer.of("DISTANCE_SENSOR") == []
        wait_for(lambda: "uav-depth: blind (stale)" in peer.texts(), 30, daemon, "the blind STATUSTEXT")
        assert any(b.system_status == 5 for b in peer.of("HEARTBEAT"))     # CRITICAL while stale
    finally:
        daemon.close()
    normal = Receiver(autopilot=True)
    daemon = Daemon(tmp_path, f"udpout:127.0.0.1:{normal.port}")
    try:
        wait_for(lambda: len(normal.of("DISTANCE_SENSOR")) >= 10, 90, daemon, "10 readings")
    finally:
        daemon.close()
        normal.close()
    for m in normal.of("DISTANCE_SENSOR"):
        assert m.min_distance < m.current_distance <= m.max_distance and m.signal_quality != 1
        assert m.current_distance <= 80 * 1.03                             # the branch at 0.8 m, never farther


def test_a_stalled_tcp_peer_gets_no_old_distances_and_its_return_is_taken_at_once(tmp_path):
    # item 2: a tcpin peer stopped for 10 s received 195 queued readings, 0.3-10 s old, on resume;
    # its reconnect took 4.4 s
    port = free_port(socket.SOCK_STREAM)
    daemon = Daemon(tmp_path, f"tcpin:127.0.0.1:{port}")
    peer = None
    try:
        deadline = time.monotonic() + 60
        while peer is None:
            try:
                peer = Receiver(f"tcp:127.0.0.1:{port}", autopilot=True)
            except OSError:
                assert time.monotonic() < deadline, daemon.stderr()[-2000:]
                time.sleep(0.2)
        wait_for(lambda: len(peer.of("DISTANCE_SENSOR")) >= 10, 90, daemon, "10 readings")
        peer.pause()                                   # SIGSTOP-like: it reads and answers nothing
        time.sleep(4.0)
        peer.resume()
        t_resume = time.monotonic()
        wait_for(lambda: len(peer.of("DISTANCE_SENSOR", since=t_resume)) >= 10, 30, daemon, "readings after resume")
        after = peer.timed("DISTANCE_SENSOR", since=t_resume)
        # 0.2 s of slack for this peer's own thread on a loaded machine; the backlog is seconds old
        old = [age_ms(t, m) for t, m in after if age_ms(t, m) > MAX_AGE_MS + 200]
        # each reading is written only after the peer answered a TIMESYNC sent just before it, so at most
        # one can be waiting for it (if it stopped between answering and reading), not the 4 s backlog
        # (about 40 at 10 frames/s)
        assert len(old) <= 1, old
        # the peer goes away and comes back on a new connection: taken at once
        peer.close()
        time.sleep(1.0)
        t_back = time.monotonic()
        peer = Receiver(f"tcp:127.0.0.1:{port}", autopilot=True)
        wait_for(lambda: peer.of("DISTANCE_SENSOR"), 10, daemon, "readings after reconnecting")
        t_first = peer.timed("DISTANCE_SENSOR")[0][0]
        assert t_first - t_back < 2.0, f"{t_first - t_back:.2f} s"         # goal: 1 s (bench/link_flood.py)
    finally:
        daemon.close()
        if peer is not None:
            peer.close()


@pytest.mark.parametrize("case", ["answers no TIMESYNC", "answers TIMESYNC unsigned, signing on"])
def test_a_tcp_peer_that_cannot_show_it_reads_gets_no_old_readings(tmp_path, case):
    # issue 44 item 4: a peer that does not answer TIMESYNC was written to directly; stopped for 10 s it
    # received 188 readings older than 300 ms on resume (192 with signing on and the answers unsigned,
    # which signing drops). On TCP a measurement now goes out only after an answer the link accepts.
    port = free_port(socket.SOCK_STREAM)
    mavlink = {}
    if "signing" in case:
        key = tmp_path / "mavlink.key"
        key.write_text("correct horse battery staple\n")
        key.chmod(0o600)
        mavlink["signing_key_file"] = str(key)
    daemon = Daemon(tmp_path, f"tcpin:127.0.0.1:{port}", mavlink=mavlink)
    peer = None
    try:
        deadline = time.monotonic() + 60
        while peer is None:
            try:
                peer = Receiver(f"tcp:127.0.0.1:{port}", autopilot="unsigned" in case)
            except OSError:
                assert time.monotonic() < deadline, daemon.stderr()[-2000:]
                time.sleep(0.2)
        wait_for(lambda: "ready:" in daemon.stderr() and len(peer.of("HEARTBEAT")) >= 3, 90, daemon,
                 "start-up and 3 heartbeats")
        peer.pause()                                   # SIGSTOP-like: it reads and answers nothing
        time.sleep(4.0)
        peer.resume()
        t_resume = time.monotonic()
        wait_for(lambda: len(peer.of("HEARTBEAT", since=t_resume)) >= 2, 30, daemon, "heartbeats after resume")
        time.sleep(1.0)
        old = [age_ms(t, m) for t, m in peer.timed("DISTANCE_SENSOR", since=t_resume) if age_ms(t, m) > MAX_AGE_MS]
    finally:
        daemon.close()
        if peer is not None:
            peer.close()
    assert old == [], f"{len(old)} readings older than {MAX_AGE_MS:g} ms after the resume, oldest {max(old):.0f} ms"
    assert "answers no TIMESYNC request" in daemon.stderr()        # the operator is told why nothing goes out


def test_the_autopilot_coming_back_on_tcp_is_reconnected_within_a_second(tmp_path):
    # item 2: the daemon as TCP client (SITL's TCP port); the reconnect back-off used to reach 10 s
    port = free_port(socket.SOCK_STREAM)
    peer = Receiver(f"tcpin:127.0.0.1:{port}", autopilot=True)
    daemon = Daemon(tmp_path, f"tcp:127.0.0.1:{port}")
    try:
        wait_for(lambda: len(peer.of("DISTANCE_SENSOR")) >= 5, 90, daemon, "5 readings")
        peer.close()
        time.sleep(8.0)                                 # long enough for a doubling back-off to grow
        peer = Receiver(f"tcpin:127.0.0.1:{port}", autopilot=True)
        t_back = time.monotonic()
        wait_for(lambda: peer.of("DISTANCE_SENSOR"), 20, daemon, "readings after the peer's return")
        took = peer.timed("DISTANCE_SENSOR")[0][0] - t_back
        assert took < 1.5, f"{took:.2f} s"            # goal 1 s; slack for a loaded machine's next frame
    finally:
        daemon.close()
        peer.close()


def _daemon_address(peer):
    deadline = time.monotonic() + 10
    while not peer.conn.clients and time.monotonic() < deadline:
        time.sleep(0.02)
    return next(iter(peer.conn.clients))


class StatusWatch:
    """The daemon's status lines as they appear: (when this test saw it, readings made, lost)."""

    PATTERN = re.compile(r"\((\d+) readings made, (\d+) lost")

    def __init__(self, daemon):
        self.daemon = daemon
        self.seen: list[tuple[float, int, int]] = []
        self._lines = 0

    def poll(self) -> None:
        lines = _status_lines(self.daemon)
        now = time.monotonic()
        for line in lines[self._lines:]:
            m = self.PATTERN.search(line)
            if m:
                self.seen.append((now, int(m.group(1)), int(m.group(2))))
        self._lines = len(lines)

    def next_after(self, t: float, timeout_s: float = 30.0) -> tuple[float, int, int]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.poll()
            later = [s for s in self.seen if s[0] > t]
            if later:
                return later[0]
            time.sleep(0.02)
        raise AssertionError(f"no status line after {t:.1f}: {self.daemon.stderr()[-2000:]}")


def test_inbound_floods_do_not_stall_the_stream_or_grow_memory(tmp_path, peer):
    # item 3: 20 KB random datagrams at 100/s gave a 2.0 s gap (ArduPilot drops the sensor after 0.5 s),
    # 65 KB zero datagrams 1.5 s; RSS grew 30 MB. The flood comes from the autopilot's own address, the
    # only one the daemon's connected udpout socket still hears.
    # A loaded machine slows the stereo stage: fewer readings, longer gaps between them, whatever the link
    # does (issue 44 item 11: a 0.693 s gap at load 12). So the test asks what a stalled link would
    # change: readings made but never written (the daemon's own count, 'lost', read from the status lines
    # before and after the flood), and readings older than their deadline by their own capture stamps.
    daemon = Daemon(tmp_path, f"udpout:127.0.0.1:{peer.port}")
    status = StatusWatch(daemon)
    try:
        wait_for(lambda: len(peer.of("DISTANCE_SENSOR")) >= 10, 90, daemon, "10 readings")
        status.next_after(time.monotonic())
        rss0 = daemon.rss_kb()
        target = _daemon_address(peer)
        sock = peer.conn.port
        rng = __import__("random").Random(13)
        t_flood = time.monotonic()
        before = status.seen[-1]
        for junk in ([rng.randbytes(20_000) for _ in range(8)], [bytes(65_000)], [rng.randbytes(900) for _ in range(8)]):
            end = time.monotonic() + 2.0
            i = 0
            while time.monotonic() < end:
                sock.sendto(junk[i % len(junk)], target)
                i += 1
                time.sleep(0.01 if len(junk[0]) > 1000 else 0.002)
        t_end = time.monotonic()
        after = status.next_after(t_end + 0.5)
        rss1 = daemon.rss_kb()
        during = [(t, m) for t, m in peer.timed("DISTANCE_SENSOR", since=before[0]) if t <= after[0]]
    finally:
        daemon.close()
    made, lost = after[1] - before[1], after[2] - before[2]
    assert made >= 10, f"only {made} readings made in {after[0] - before[0]:.1f} s"   # the stereo stage ran
    assert lost == 0, f"the link lost {lost} of the {made} readings made during the flood"
    ages = [age_ms(t, m) for t, m in during]
    # the peer got them (between the two lines as this test saw them: a reading either side may be cut)
    assert len(during) >= made - 2 and max(ages) <= MAX_AGE_MS, (len(during), made, max(ages))
    assert rss1 - rss0 < 20_000, f"RSS grew {rss1 - rss0} kB"                  # goal 5 MB: bench/link_flood.py


def test_time_boot_ms_is_the_capture_time_strictly_increasing(tmp_path, peer):
    # item 8: time_boot_ms was the send time and a catch-up tick repeated it
    daemon = Daemon(tmp_path, f"udpout:127.0.0.1:{peer.port}")
    try:
        wait_for(lambda: len(peer.of("DISTANCE_SENSOR")) >= 30, 120, daemon, "30 readings")
    finally:
        daemon.close()
    ds = peer.timed("DISTANCE_SENSOR")
    stamps = [m.time_boot_ms for _, m in ds]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))               # never repeated, never reordered
    ages = sorted(age_ms(t, m) for t, m in ds)
    # capture to arrival: at least the stereo stage (several ms), never more than max_age_ms
    assert ages[0] >= 1 and ages[-1] <= MAX_AGE_MS, (ages[0], ages[-1])


def _status_lines(daemon):
    return [line.split("status: ", 1)[1] for line in daemon.stderr().splitlines() if "status: " in line]


def test_the_status_line_counts_what_reached_an_autopilot_and_says_when_none_is_heard(tmp_path):
    # issue 47 item 3: with nobody listening, "sent 151/151 valid": queued messages counted as sent
    port = free_port()
    url = f"udpin:127.0.0.1:{port}"
    daemon = Daemon(tmp_path, url)
    try:
        wait_for(lambda: len(_status_lines(daemon)) >= 3, 90, daemon, "3 status lines")
        lonely = _status_lines(daemon)[-1]
        autopilot = Receiver(f"udpout:127.0.0.1:{port}", sysid=1, compid=1, autopilot=True)
        try:
            wait_for(lambda: len(autopilot.of("DISTANCE_SENSOR")) >= 10, 60, daemon, "10 readings")
            n_seen = len(autopilot.of("DISTANCE_SENSOR"))
            t = time.monotonic()
            wait_for(lambda: any("to autopilot" in s for s in _status_lines(daemon)[-1:])
                     and time.monotonic() - t > 1.5, 30, daemon, "a status line with the autopilot")
            heard = _status_lines(daemon)[-1]
        finally:
            autopilot.close()
    finally:
        daemon.close()
    assert re.search(f"NO AUTOPILOT HEARD on {url}: 0 of [0-9]+ readings delivered", lonely), lonely
    sent = re.search(r"sent (\d+)/(\d+) valid to autopilot 1/1 \((\d+) readings made, \d+ lost\)", heard)
    assert sent, heard
    valid, delivered, made = map(int, sent.groups())
    assert 0 < valid <= delivered <= made and delivered >= n_seen - 2, (heard, n_seen)
