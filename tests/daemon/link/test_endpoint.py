"""The link's endpoint against real pymavlink endpoints on loopback: the send clock, fields, a dead thread, the wrap."""

import threading
import time

import pytest

from uav_depth.core.ranging import Measurement, RangeLimits
from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.estimate import Estimate
from uav_depth.daemon.link.clock import SendClock
from uav_depth.daemon.link.endpoint import MavlinkLink

from mavlink_peer import Receiver, free_port


LIMITS = RangeLimits(min_distance_m=0.345, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)


def estimate(distance=1.234, sigma=0.01, quality=80, t_capture=10.0, limits=LIMITS):
    m = Measurement(distance, sigma, quality) if distance is not None else Measurement(None, reason="none")
    return Estimate(m, limits, t_capture, t_capture + 0.05, 7, "abc")


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


def test_a_message_whose_builder_raises_is_dropped_and_the_link_goes_on():
    # issue 44 item 3: builders run on the I/O thread, which caught only ConnectionError/OSError: one bad
    # builder ended the thread, and every later message was queued for nobody
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}")).start()
    try:
        assert link.wait_connected(2)
        link.send(lambda mav: mav.no_such_message_encode(), kind="broken")         # a builder with a bug
        deadline = time.monotonic() + 5
        while "after the bug" not in peer.texts() and time.monotonic() < deadline:
            link.statustext("after the bug")
            time.sleep(0.05)
        assert "after the bug" in peer.texts()
        assert link.alive and link.count.build_errors == 1
    finally:
        link.close()
        peer.close()
    assert not link.alive                                          # closed: the thread is gone


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_the_service_is_unhealthy_once_the_link_thread_is_dead():
    # issue 44 item 3: with the I/O thread dead, `connected` stayed True and the watchdog stayed fed
    from uav_depth.daemon.config import ServiceConfig
    from uav_depth.daemon.health import Health
    from uav_depth.daemon.notify import Notifier
    from uav_depth.daemon.state import ServiceState

    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=1, compid=1, autopilot=True)
    cfg = MavlinkConfig(url=f"udpout:127.0.0.1:{port}")
    link = MavlinkLink(cfg).start()
    clock = SendClock(link, cfg, 0.3, estimate=lambda: None, limits=lambda: LIMITS, state=lambda: "boot").start()
    health = Health(ServiceConfig(), Notifier(), ServiceState(), lambda: "")
    health.watch("mavlink-io", link)
    health.watch("mavlink-clock", clock)
    try:
        assert link.wait_connected(2)
        assert health.healthy()

        def dies(msg):            # the one seam: something on the I/O thread that even a catch-all lets through
            raise SystemExit("the I/O thread ends here")
        link.subscribe("HEARTBEAT", dies)
        deadline = time.monotonic() + 10
        while link.alive and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not link.alive
        assert clock.alive and not health.healthy()                # the watchdog is no longer fed
        assert health.dead == ("mavlink-io",)
    finally:
        clock.stop()
        link.close()
        peer.close()


def test_readings_keep_flowing_across_the_49_7_day_wrap_of_time_boot_ms():
    # issue 44 item 8: time_boot_ms is masked to 32 bits and was compared with '>': after 49.7 days of
    # uptime (2^32 ms) every new stamp looked older than the last one sent, and nothing was sent again
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    cfg = MavlinkConfig(url=f"udpout:127.0.0.1:{port}", rate_hz=100, proximity_commit=True)
    link = MavlinkLink(cfg).start()
    pub = Publisher(period_s=0.02)
    clock = SendClock(link, cfg, 0.3, estimate=lambda: pub.est, limits=lambda: LIMITS, state=lambda: "active")
    clock.t_start = time.monotonic() - (2**32 - 600) / 1000.0     # the stamps wrap 0.6 s from now
    clock.start()
    try:
        assert peer.wait(lambda: any(m.time_boot_ms < 10_000 and m.time_boot_ms != 2**32 - 1
                                     for m in peer.of("DISTANCE_SENSOR")), 10)
        t_wrap = time.monotonic()
        time.sleep(1.0)                                             # and a second of readings after it
    finally:
        clock.stop()
        pub.close()
        link.close()
        peer.close()
    from uav_depth.daemon.link.contract import boot_ms

    captured = {boot_ms(e.t_capture, clock.t_start) for e in pub.published}
    ds = peer.of("DISTANCE_SENSOR")
    readings = [m for m in ds if m.time_boot_ms in captured]
    copies = [m for m in ds if m.time_boot_ms not in captured]
    assert all((c.time_boot_ms + 1) % 2**32 in captured for c in copies)     # each copy 1 ms before its reading
    after = [m for _, m in peer.timed("DISTANCE_SENSOR", since=t_wrap) if m.time_boot_ms in captured]
    assert any(m.time_boot_ms > 2**31 for m in readings) and len(after) >= 20, len(after)   # ~50 in that second
    unwrapped = [t + (2**32 if t < 2**31 else 0) for t in (m.time_boot_ms for m in readings)]
    assert all(b > a for a, b in zip(unwrapped, unwrapped[1:]))     # strictly in order across the wrap
