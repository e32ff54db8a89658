"""MAVLink output against real pymavlink endpoints on loopback: fields, clock, subscriptions, signing, reconnects."""

import math
import os
import socket
import threading
import time

import pytest

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.core.errors import ConfigError
from uav_depth.daemon.mavlink_out import (MavlinkLink, SendClock, distance_report, load_signing_key,
                                          orientation_code)
from uav_depth.daemon.mavlink_enums import mavutil
from uav_depth.daemon.ranging import Estimate, Measurement, RangeLimits

from mavlink_peer import Receiver, free_port

LIMITS = RangeLimits(min_distance_m=0.345, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)


def estimate(distance=1.234, sigma=0.01, quality=80, t_capture=10.0, limits=LIMITS):
    m = Measurement(distance, sigma, quality) if distance is not None else Measurement(None, reason="none")
    return Estimate(m, limits, t_capture, t_capture + 0.05, 7, "abc")


def test_fresh_estimate_fields():
    r = distance_report(estimate(), LIMITS, now=10.25, max_age_s=0.3, t_start=9.0)
    assert r.condition == "measuring" and r.sent and r.valid
    assert r.current_distance == 123 and (r.min_distance, r.max_distance) == (33, 1000)   # min 0.345 m: 34 - 1
    assert r.covariance == 1 and r.signal_quality == 80 and r.age_ms == 250
    assert r.time_boot_ms == 1000                               # the capture time, not the send time
    assert (r.horizontal_fov, r.vertical_fov) == (0.6, 0.35)
    r = distance_report(estimate(sigma=0.05), LIMITS, now=10.1, max_age_s=0.3, t_start=9.0)
    assert r.covariance == 25                                   # (5 cm)^2


def test_a_reading_at_the_minimum_goes_out_strictly_above_min_distance():
    # issue 13 item 1: min 0.2749 m was rounded up to 28 cm and the reading to nearest (27): sent as max + 1
    lim = RangeLimits(min_distance_m=0.2749, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)
    r = distance_report(estimate(0.2749, limits=lim), lim, 10.0, 0.3)
    assert r.condition == "measuring" and r.current_distance == 27
    assert r.min_distance < r.current_distance <= r.max_distance   # PX4 needs current > min


@pytest.mark.parametrize("d,cm", [(1.2399, 123), (0.29, 29), (0.999999, 99), (2.0, 200), (0.345, 34)])
def test_readings_are_rounded_down_never_farther(d, cm):
    lim = RangeLimits(min_distance_m=0.2, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)
    if d == 0.345:
        lim = LIMITS
    assert distance_report(estimate(d, limits=lim), lim, 10.0, 0.3).current_distance == cm


def test_too_close_is_the_nearest_value_both_autopilots_take_as_an_obstacle():
    est = Estimate(Measurement(None, reason="too close"), LIMITS, 10.0, 10.05, 7, "abc", too_close=True)
    r = distance_report(est, LIMITS, 10.1, 0.3)
    assert r.condition == "too close" and r.sent and not r.valid
    assert r.current_distance == r.min_distance + 1 == 34        # > min (PX4), within min..max (ArduPilot)
    assert r.current_distance <= 100 * LIMITS.min_distance_m     # never farther than the minimum range
    assert r.covariance == 255 and r.signal_quality != 1
    # a reading below the wire's minimum is too close too, never dropped to "clear"
    r = distance_report(estimate(0.30), LIMITS, 10.0, 0.3)
    assert r.condition == "too close" and r.current_distance == 34


@pytest.mark.parametrize("case,condition", [
    ("stale", "stale"), ("none", "starting"), ("no-measurement", "nothing confident"),
    ("out-of-range", "nothing confident"), ("camera lost", "camera lost"),
    ("parameters unusable", "parameters unusable"), ("shutting down", "shutting down")])
def test_blind_sends_nothing(case, condition):
    est = {"stale": estimate(t_capture=9.0), "none": None, "no-measurement": estimate(distance=None),
           "out-of-range": estimate(distance=20.0)}.get(case, estimate())
    blind = case if case in ("camera lost", "parameters unusable", "shutting down") else None
    r = distance_report(est, LIMITS, now=10.0, max_age_s=0.3, blind=blind)
    assert r.condition == condition and not r.sent and r.current_distance is None


def test_signal_quality_is_never_1():
    assert distance_report(estimate(quality=1), LIMITS, 10.0, 0.3).signal_quality == 2
    assert distance_report(estimate(quality=100), LIMITS, 10.0, 0.3).signal_quality == 100


def test_covariance_is_never_zero_and_never_smaller_than_the_sigma():
    tiny = distance_report(estimate(sigma=1e-5), LIMITS, 10.0, 0.3, 0.0)
    assert tiny.covariance == 1
    # 254 cm^2 is the largest the uint8 field carries (15.9 cm); beyond, "unknown" (255), never a
    # clipped 254 that would tell the autopilot the reading is more precise than it is.
    at_cap = distance_report(estimate(sigma=math.sqrt(254) / 100), LIMITS, 10.0, 0.3, 0.0)
    over = distance_report(estimate(sigma=0.16), LIMITS, 10.0, 0.3, 0.0)
    huge = distance_report(estimate(sigma=1.0), LIMITS, 10.0, 0.3, 0.0)
    assert at_cap.covariance == 254 and over.covariance == 255 and huge.covariance == 255
    assert over.valid and over.current_distance is not None    # the distance itself is what was measured


def test_orientation_code_rejects_nonsense():
    with pytest.raises(ValueError):
        orientation_code("sideways")
    with pytest.raises(ValueError):
        orientation_code(100)


class Publisher:
    """A stereo loop stand-in: a new estimate every ``period_s``, captured now (or blind when ``blind`` is set)."""

    def __init__(self, period_s=0.02, distance=1.234):
        self.est = None
        self.blind = False
        self.published = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, args=(period_s, distance), daemon=True)
        self._t.start()

    def _loop(self, period_s, distance):
        while not self._stop.wait(period_s):
            now = time.monotonic()
            self.est = estimate(distance=None if self.blind else distance, t_capture=now)
            self.published.append(self.est)

    def close(self):
        self._stop.set()
        self._t.join(1)


def test_send_clock_sends_each_estimate_once_stamped_with_its_capture_time():
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    cfg = MavlinkConfig(url=f"udpout:127.0.0.1:{port}", rate_hz=200, sensor_id=3, orientation="down",
                        sensor_type="radar")
    link = MavlinkLink(cfg).start()
    pub = Publisher()
    clock = SendClock(link, cfg, 0.3, estimate=lambda: pub.est, limits=lambda: LIMITS, state=lambda: "active").start()
    try:
        ds = peer.wait_for("DISTANCE_SENSOR", count=30)
        hb = peer.wait_for("HEARTBEAT", count=1)
        pub.blind = True                                           # the stereo loop measures nothing
        time.sleep(0.2)
        t_blind = time.monotonic()
        time.sleep(0.5)
        blind = peer.of("DISTANCE_SENSOR", since=t_blind)
        told = peer.wait(lambda: "uav-depth: blind (nothing confident)" in peer.texts(), 5)
    finally:
        clock.stop()
        pub.close()
        link.close()
        peer.close()
    m = ds[-1]
    assert (m.current_distance, m.min_distance, m.max_distance) == (123, 33, 1000)
    assert (m.id, m.orientation, m.type, m.signal_quality, m.covariance) == (3, 25, 3, 80, 1)
    assert m.horizontal_fov == pytest.approx(0.6) and m.vertical_fov == pytest.approx(0.35)
    stamps = [x.time_boot_ms for x in ds]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))       # strictly increasing, never repeated
    captured = {int(e.t_capture * 1000) & 0xFFFFFFFF for e in pub.published}
    assert set(stamps) <= captured                               # each one an estimate's capture time
    assert (hb[0].type, hb[0].autopilot, hb[0].system_status) == (18, 8, 4)
    assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
    assert m.get_msgbuf()[0] == 0xFD                              # MAVLink 2
    assert blind == []                                            # blind: nothing at all
    assert told


def test_proximity_commit_follows_each_reading_with_its_copy_stamped_1_ms_earlier():
    # ArduPilot's AP_Proximity_MAV applies a DISTANCE_SENSOR only when a message with another
    # time_boot_ms arrives: the copy closes each reading at once, and says nothing new.
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    cfg = MavlinkConfig(url=f"udpout:127.0.0.1:{port}", rate_hz=50, proximity_commit=True)
    link = MavlinkLink(cfg).start()
    pub = Publisher(period_s=0.04)
    clock = SendClock(link, cfg, 0.3, estimate=lambda: pub.est, limits=lambda: LIMITS, state=lambda: "active").start()
    try:
        ds = peer.wait_for("DISTANCE_SENSOR", count=20)
        pub.blind = True
        time.sleep(0.2)
        t_blind = time.monotonic()
        time.sleep(0.4)
        blind = peer.of("DISTANCE_SENSOR", since=t_blind)
    finally:
        clock.stop()
        pub.close()
        link.close()
        peer.close()
    captured = {int(e.t_capture * 1000) & 0xFFFFFFFF for e in pub.published}
    stamps = [m.time_boot_ms for m in ds]
    start = next(i for i, t in enumerate(stamps) if t in captured)
    pairs = list(zip(ds[start::2], ds[start + 1::2]))
    assert len(pairs) >= 8
    fields = lambda m: (m.current_distance, m.min_distance, m.max_distance, m.covariance,  # noqa: E731
                        m.signal_quality, m.orientation, m.id)
    for reading, copy in pairs:
        assert reading.time_boot_ms in captured                  # the reading: its capture time
        assert copy.time_boot_ms == reading.time_boot_ms - 1     # the copy: 1 ms earlier, never newer
        assert fields(copy) == fields(reading)                   # the same measurement
    readings = [r.time_boot_ms for r, _ in pairs]
    assert all(b > a for a, b in zip(readings, readings[1:]))
    assert blind == []                                           # blind: neither reading nor copy


def test_subscribe_and_message_interval_over_the_same_connection():
    port = free_port()
    autopilot = Receiver(f"udpin:127.0.0.1:{port}", sysid=1, compid=1)
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}")).start()
    got = []
    link.subscribe("LOCAL_POSITION_NED", got.append)
    link.request_message_interval("LOCAL_POSITION_NED", 20)      # before the autopilot is known
    try:
        link.wait_connected(2)
        link.heartbeat()                                          # the autopilot learns our address
        autopilot.wait_for("HEARTBEAT")
        mav = autopilot.conn.mav
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            mav.heartbeat_send(2, 3, 0, 0, 4)                     # quadrotor, ArduPilot
            mav.local_position_ned_send(1234, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3)
            time.sleep(0.05)
        assert got and (got[0].x, got[0].y, got[0].z) == (1.0, 2.0, -3.0)
        assert link.autopilot == (1, 1)
        cmds = autopilot.wait_for("COMMAND_LONG", pred=lambda m: m.command == 511)
        assert cmds[-1].param1 == 32 and cmds[-1].param2 == pytest.approx(50000)
        assert (cmds[-1].target_system, cmds[-1].target_component) == (1, 1)
    finally:
        link.close()
        autopilot.close()


def test_signing_key_file_permissions_and_signed_messages(tmp_path):
    key_file = tmp_path / "mavlink.key"
    key_file.write_text("correct horse battery staple\n")
    key_file.chmod(0o644)
    with pytest.raises(ConfigError, match="must not be accessible by group or others"):
        load_signing_key(key_file)
    key_file.chmod(0o600)
    key = load_signing_key(key_file)
    assert len(key) == 32
    big = tmp_path / "big.key"
    big.write_bytes(b"x" * 5000)
    big.chmod(0o600)
    with pytest.raises(ConfigError, match=r"must be a regular file of at most 4096 bytes, but got '.*big\.key \(5000 bytes\)'"):
        load_signing_key(big)
    fifo = tmp_path / "fifo.key"
    os.mkfifo(fifo, 0o600)              # reading it would wait for a writer
    with pytest.raises(ConfigError, match=r"must be a regular file of at most 4096 bytes"):
        load_signing_key(fifo)
    hex_file = tmp_path / "hex.key"
    hex_file.write_text(key.hex())
    hex_file.chmod(0o600)
    assert load_signing_key(hex_file) == key
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    peer.conn.setup_signing(key, sign_outgoing=False)             # rejects anything not signed with the key
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", signing_key_file=key_file)).start()
    try:
        link.wait_connected(2)
        deadline = time.monotonic() + 5
        while not peer.of("STATUSTEXT") and time.monotonic() < deadline:
            link.statustext("uav-depth: signed hello")
            time.sleep(0.05)
        msg = peer.wait_for("STATUSTEXT")[0]
        assert msg.text == "uav-depth: signed hello" and msg._signed
    finally:
        link.close()
        peer.close()


def test_tcp_link_without_peer_never_blocks_and_reconnects():
    port = free_port(socket.SOCK_STREAM)
    link = MavlinkLink(MavlinkConfig(url=f"tcp:127.0.0.1:{port}"), reconnect_min_s=0.05,
                       reconnect_max_s=0.2).start()
    try:
        start = time.monotonic()
        assert not link.send(lambda mav: mav.heartbeat_encode(18, 8, 0, 0, 4))   # nobody there: dropped
        assert time.monotonic() - start < 0.1 and link.dropped == 1
        server = Receiver(f"tcpin:127.0.0.1:{port}", sysid=255, compid=190)
        assert link.wait_connected(5)
        deadline = time.monotonic() + 5
        while not server.of("HEARTBEAT") and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
        server.wait_for("HEARTBEAT")
        server.close()                                               # the autopilot goes away
        deadline = time.monotonic() + 5
        while link.connected and time.monotonic() < deadline:        # noticed, and retrying quietly
            link.heartbeat()
            time.sleep(0.05)
        assert not link.connected
        server = Receiver(f"tcpin:127.0.0.1:{port}", sysid=255, compid=190)   # and comes back
        deadline = time.monotonic() + 5
        while not server.of("HEARTBEAT") and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
        server.wait_for("HEARTBEAT")
        server.close()
    finally:
        assert link.close()


def test_udpout_is_bound_to_loopback_and_hears_only_the_autopilot():
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=1, compid=1, autopilot=True)
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}")).start()
    got = []
    link.subscribe("HEARTBEAT", got.append)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert link.wait_connected(2)
        local = link._t.local
        assert local[0] == "127.0.0.1"                              # never 0.0.0.0
        link.heartbeat()
        assert peer.wait(lambda: got, 5)                            # the autopilot is heard
        enc = mavutil().mavlink.MAVLink(None, 42, 1)                # a stranger's valid HEARTBEAT to our port
        n = len(got)
        for _ in range(5):
            stranger.sendto(enc.heartbeat_encode(2, 3, 0, 0, 4).pack(enc), local)
            time.sleep(0.05)
        time.sleep(0.3)
        assert all(m.get_srcSystem() == 1 for m in got[n:])         # the kernel drops the stranger's datagrams
    finally:
        stranger.close()
        link.close()
        peer.close()


def test_serial_link_through_a_pseudo_terminal():
    master, slave = os.openpty()
    link = MavlinkLink(MavlinkConfig(url=os.ttyname(slave), baud=57600)).start()
    parser = mavutil().mavlink.MAVLink(None, 255, 0)
    parser.robust_parsing = True
    got = []
    try:
        assert link.wait_connected(2)
        deadline = time.monotonic() + 5
        os.set_blocking(master, False)
        while not got and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            got += [m for m in parser.parse_buffer(data) or () if m.get_type() == "HEARTBEAT"]
        assert got and (got[0].get_srcSystem(), got[0].get_srcComponent()) == (1, 191)
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def test_bytes_the_kernel_holds_past_their_deadline_are_discarded_with_a_reset():
    # a TCP peer whose window is closed (tiny receive buffer, never reads, never answers TIMESYNC):
    # what waits in our kernel would arrive old, so the connection is reset instead
    port = free_port(socket.SOCK_STREAM)
    cfg = MavlinkConfig(url=f"tcpin:127.0.0.1:{port}", rate_hz=200)
    link = MavlinkLink(cfg).start()
    pub = Publisher(period_s=0.005)
    clock = SendClock(link, cfg, 0.2, estimate=lambda: pub.est, limits=lambda: LIMITS, state=lambda: "active").start()
    peer = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    peer.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    try:
        assert link.wait_connected(2)
        peer.connect(("127.0.0.1", port))
        deadline = time.monotonic() + 20
        while link.discards == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.discards >= 1
        peer.settimeout(2)
        with pytest.raises(ConnectionResetError):       # after what its buffer held: the reset
            while peer.recv(65536):
                pass
    finally:
        clock.stop()
        pub.close()
        link.close()
        peer.close()


def test_the_stated_range_ends_where_readings_stop_being_precise():
    """max_distance is the nearer of the range and the precise range (ranging.max_sigma_m)."""
    lim = RangeLimits(min_distance_m=0.345, max_distance_m=7.0, hfov_rad=0.6, vfov_rad=0.35, precise_max_m=2.4671)
    r = distance_report(estimate(distance=2.0, limits=lim), lim, 10.0, 0.3, 0.0)
    assert r.max_distance == 246 and r.valid
    beyond = distance_report(estimate(distance=2.6, limits=lim), lim, 10.0, 0.3, 0.0)
    assert not beyond.sent
