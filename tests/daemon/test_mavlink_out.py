"""MAVLink output against real pymavlink endpoints on loopback: fields, clock, subscriptions, signing, reconnects."""

import socket
import time

import pytest

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.core.errors import ConfigError
from uav_depth.daemon.mavlink_out import (MavlinkLink, SendClock, distance_report, load_signing_key,
                                          orientation_code)
from uav_depth.daemon.ranging import Estimate, Measurement, RangeLimits

from mavlink_peer import Receiver, free_port

LIMITS = RangeLimits(min_distance_m=0.345, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)


def estimate(distance=1.234, sigma=0.01, quality=80, t_capture=10.0, limits=LIMITS):
    m = Measurement(distance, sigma, quality) if distance is not None else Measurement(None, reason="none")
    return Estimate(m, limits, t_capture, t_capture + 0.05, 7, "abc")


def test_fresh_estimate_fields():
    r = distance_report(estimate(), LIMITS, now=10.25, max_age_s=0.3, t_start=9.0)
    assert r.valid and r.current_distance == 123 and (r.min_distance, r.max_distance) == (35, 1000)
    assert r.covariance == 1 and r.signal_quality == 80 and r.time_boot_ms == 1250 and r.age_ms == 250
    assert (r.horizontal_fov, r.vertical_fov) == (0.6, 0.35)
    r = distance_report(estimate(sigma=0.05), LIMITS, now=10.1, max_age_s=0.3, t_start=9.0)
    assert r.covariance == 25                                   # (5 cm)^2


@pytest.mark.parametrize("case", ["stale", "none", "no-measurement", "out-of-range"])
def test_no_measurement_is_said_as_the_spec_says(case):
    est = {"stale": estimate(t_capture=9.0), "none": None, "no-measurement": estimate(distance=None),
           "out-of-range": estimate(distance=20.0)}[case]
    r = distance_report(est, LIMITS, now=10.0, max_age_s=0.3, t_start=0.0)
    assert not r.valid and r.signal_quality == 1 and r.covariance == 255
    assert r.current_distance > r.max_distance                   # outside min..max, never a made-up distance


def test_covariance_is_never_zero_and_huge_spread_saturates():
    tiny = distance_report(estimate(sigma=1e-5), LIMITS, 10.0, 0.3, 0.0)
    huge = distance_report(estimate(sigma=1.0), LIMITS, 10.0, 0.3, 0.0)
    assert tiny.covariance == 1 and huge.covariance == 254


def test_orientation_code_rejects_nonsense():
    with pytest.raises(ValueError):
        orientation_code("sideways")
    with pytest.raises(ValueError):
        orientation_code(100)


def test_send_clock_heartbeat_and_distance_on_a_real_endpoint():
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    cfg = MavlinkConfig(url=f"udpout:127.0.0.1:{port}", rate_hz=25, sensor_id=3, orientation="down",
                        sensor_type="radar")
    link = MavlinkLink(cfg).start()
    now = time.monotonic
    est = estimate(t_capture=now() + 3600)     # "captured in the future": fresh for the whole test
    clock = SendClock(link, cfg, 0.3, estimate=lambda: est, limits=lambda: LIMITS, state=lambda: "active").start()
    try:
        ds = peer.wait_for("DISTANCE_SENSOR", count=30)
        hb = peer.wait_for("HEARTBEAT", count=1)
    finally:
        clock.stop()
        link.close()
        peer.close()
    m = ds[-1]
    assert (m.current_distance, m.min_distance, m.max_distance) == (123, 35, 1000)
    assert (m.id, m.orientation, m.type, m.signal_quality, m.covariance) == (3, 25, 3, 80, 1)
    assert m.horizontal_fov == pytest.approx(0.6) and m.vertical_fov == pytest.approx(0.35)
    stamps = [x.time_boot_ms for x in ds]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))       # advances every message
    assert (hb[0].type, hb[0].autopilot, hb[0].system_status) == (18, 8, 4)
    assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
    assert m.get_msgbuf()[0] == 0xFD                              # MAVLink 2


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
