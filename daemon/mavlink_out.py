"""MAVLink 2 output: the link to the autopilot and the DISTANCE_SENSOR send clock.

:class:`MavlinkLink` owns one pymavlink connection. Its I/O thread connects (and
reconnects with back-off when the serial device vanishes, the TCP peer closes,
or the port cannot be bound), reads every incoming message and hands it to
subscribers (``subscribe(msg_type, callback)``), so other parts (SITL) can read
the autopilot's LOCAL_POSITION_NED or ATTITUDE over the same connection. Sending
never waits for a connection: without one a message is dropped and counted.

:class:`SendClock` is the fixed clock: DISTANCE_SENSOR at ``rate_hz`` and HEARTBEAT
at 1 Hz, whatever the stereo loop is doing. Each tick takes the newest estimate
and sends it as valid only if it is younger than ``max_age_ms`` (measured from
frame capture); otherwise it sends "no measurement" as the MAVLink spec says:
signal_quality 1 and a current_distance outside min..max.

Field choices (see also /shared/ARDUPILOT.md): distances in cm; min/max from the
disparity search range and the calibration; covariance in cm^2, 255 (UINT8_MAX)
when unknown, never 0; FOVs of the ranging ROI in rad; time_boot_ms advances
every message (ArduPilot's proximity backend merges equal stamps).
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import select
import socket
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.mavlink_enums import (HEARTBEAT_PERIOD_S, MAV_AUTOPILOT_INVALID, MAV_CMD_SET_MESSAGE_INTERVAL,
                                            MAV_STATE, MAV_TYPE_ONBOARD_CONTROLLER, SENSOR_TYPES, SEVERITY,
                                            STATUSTEXT_LEN, UINT8_UNKNOWN, mavutil, orientation_code)
from uav_depth.core.errors import ConfigError
from uav_depth.daemon.ranging import Estimate, RangeLimits

log = logging.getLogger("uav_depth.mavlink")

def load_signing_key(path: Path) -> bytes:
    """The 32-byte MAVLink 2 signing key from ``path``.

    The file holds 64 hex digits, 32 raw bytes, or a passphrase (hashed with
    SHA-256, as MAVProxy's ``signing setup`` and Mission Planner do). A key file
    readable by group or others is refused.
    """
    key = "mavlink.signing_key_file"
    try:
        st = path.stat()
    except FileNotFoundError as exc:
        raise ConfigError(key, "must name an existing file", str(path)) from exc
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(key, "must not be accessible by group or others (chmod 600)",
                          f"{path} with mode {stat.S_IMODE(st.st_mode):04o}")
    if stat.S_ISDIR(st.st_mode):
        raise ConfigError(key, "must name a file, not a directory", str(path))
    try:
        raw = path.read_bytes()
    except OSError as exc:   # the service user cannot read it (root-owned 0600): one line, exit 78
        raise ConfigError(key, f"must be readable by this user (uid {os.getuid()}): {exc.strerror}",
                          str(path)) from exc
    text = raw.strip()
    try:
        if len(text) == 64:
            return bytes.fromhex(text.decode("ascii"))
    except (ValueError, UnicodeDecodeError):
        pass
    if len(raw) == 32:
        return raw
    if not text:
        raise ConfigError(key, "must not be empty", str(path))
    return hashlib.sha256(text).digest()


# -- the DISTANCE_SENSOR fields (pure) --------------------------------------------------------

@dataclass(frozen=True)
class DistanceReport:
    """The fields of one DISTANCE_SENSOR message (distances in cm, FOV in rad)."""

    time_boot_ms: int
    min_distance: int
    max_distance: int
    current_distance: int
    covariance: int
    signal_quality: int
    horizontal_fov: float
    vertical_fov: float
    valid: bool
    age_ms: float | None


def distance_report(estimate: Estimate | None, limits: RangeLimits, now: float, max_age_s: float,
                    t_start: float) -> DistanceReport:
    """What to send at time ``now`` (monotonic s): the estimate if fresh and in range, else "no measurement"."""
    if estimate is not None and estimate.measurement.valid:
        limits = estimate.limits      # the limits of the parameters that measured it
    max_cm = max(2, min(65534, int(math.floor(limits.max_distance_m * 100.0))))
    min_cm = max(1, min(max_cm - 1, int(math.ceil(limits.min_distance_m * 100.0))))
    age = None if estimate is None else now - estimate.t_capture
    current = None
    if estimate is not None and estimate.measurement.valid and age is not None and age <= max_age_s:
        cm = int(round(estimate.measurement.distance_m * 100.0))
        if min_cm <= cm <= max_cm:
            current = cm
    boot_ms = int((now - t_start) * 1000.0) & 0xFFFFFFFF
    if current is None:
        return DistanceReport(boot_ms, min_cm, max_cm, max_cm + 1, UINT8_UNKNOWN, 1, limits.hfov_rad,
                              limits.vfov_rad, False, None if age is None else age * 1000.0)
    m = estimate.measurement
    if m.sigma_m is None or not math.isfinite(m.sigma_m):
        cov = UINT8_UNKNOWN
    else:   # variance in cm^2; a measured 0.3 cm^2 rounds up to 1, never to 0 ("unknown" to some readers)
        cov = int(min(UINT8_UNKNOWN - 1, max(1, math.ceil((m.sigma_m * 100.0) ** 2))))
    return DistanceReport(boot_ms, min_cm, max_cm, current, cov, int(min(100, max(2, m.quality))),
                          limits.hfov_rad, limits.vfov_rad, True, age * 1000.0)


# -- the link ---------------------------------------------------------------------------------

Callback = Callable[[Any], None]


class MavlinkLink:
    """One MAVLink 2 connection with an I/O thread, subscriptions and never-blocking sends.

    Thread-safe: ``send``, ``statustext``, ``subscribe`` and
    ``request_message_interval`` may be called from any thread. Subscriber
    callbacks run on the I/O thread and must return quickly.
    """

    def __init__(self, config: MavlinkConfig, reconnect_min_s: float = 0.5, reconnect_max_s: float = 5.0):
        self.config = config
        self._mu = mavutil()
        self._key = load_signing_key(config.signing_key_file) if config.signing_key_file else None
        self._conn: Any = None
        self._lock = threading.Lock()
        self._subs: dict[str, list[Callback]] = {}
        self._subs_lock = threading.Lock()
        self._intervals: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._broken = False
        self._backoff = (reconnect_min_s, reconnect_max_s)
        self.autopilot: tuple[int, int] | None = None
        self.sent = 0
        self.dropped = 0
        self.received = 0
        self.connects = 0
        self._last_error: str | None = None

    # lifecycle
    def start(self) -> "MavlinkLink":
        if self._thread is None:
            self._thread = threading.Thread(target=self._io_loop, name="mavlink-io", daemon=True)
            self._thread.start()
        return self

    def close(self, timeout_s: float = 1.0) -> bool:
        """Stop the I/O thread and close the connection; False if the thread did not end in time."""
        self._stop.set()
        done = True
        if self._thread is not None:
            self._thread.join(timeout_s)
            done = not self._thread.is_alive()
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.close()
            except Exception:   # closing a dead port must not fail a shutdown
                pass
        return done

    @property
    def connected(self) -> bool:
        return self._conn is not None

    def wait_connected(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while self._conn is None and time.monotonic() < deadline and not self._stop.is_set():
            time.sleep(0.01)
        return self._conn is not None

    # sending
    def send(self, build: Callable[[Any], Any]) -> bool:
        """Encode with ``build(mav)`` and send now; False (and counted) when there is no connection."""
        conn = self._conn
        if conn is None or self._broken:
            self.dropped += 1
            return False
        with self._lock:
            try:
                conn.mav.send(build(conn.mav))
            except Exception as exc:   # a dead serial port or socket: the I/O thread reconnects
                self._note_error(f"send failed: {type(exc).__name__}: {exc}")
                self._broken = True
                self.dropped += 1
                return False
        self.sent += 1
        return True

    def statustext(self, text: str, severity: str = "info") -> bool:
        """Send a STATUSTEXT (cut to 50 characters; the full text goes to the log)."""
        data = text.encode("ascii", "replace")[:STATUSTEXT_LEN]
        return self.send(lambda mav: mav.statustext_encode(SEVERITY[severity], data))

    def heartbeat(self, state: str = "active") -> bool:
        return self.send(lambda mav: mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID,
                                                          0, 0, MAV_STATE[state]))

    def distance_sensor(self, r: DistanceReport, sensor_type: int, sensor_id: int, orientation: int) -> bool:
        return self.send(lambda mav: mav.distance_sensor_encode(
            r.time_boot_ms, r.min_distance, r.max_distance, r.current_distance, sensor_type, sensor_id,
            orientation, r.covariance, horizontal_fov=r.horizontal_fov, vertical_fov=r.vertical_fov,
            quaternion=(0.0, 0.0, 0.0, 0.0), signal_quality=r.signal_quality))

    # receiving
    def subscribe(self, msg_type: str, callback: Callback) -> Callable[[], None]:
        """Call ``callback(msg)`` on the I/O thread for every incoming ``msg_type`` ("*": all).

        Returns a function that removes the subscription.
        """
        with self._subs_lock:
            self._subs.setdefault(msg_type, []).append(callback)

        def unsubscribe() -> None:
            with self._subs_lock:
                if callback in self._subs.get(msg_type, []):
                    self._subs[msg_type].remove(callback)
        return unsubscribe

    def request_message_interval(self, msg_id: int | str, hz: float) -> None:
        """Ask the autopilot to stream ``msg_id`` (number or name) at ``hz`` (<= 0 stops it).

        The request is remembered and sent again whenever the link reconnects or a
        (new) autopilot appears, so it may be made before the autopilot is up.
        """
        if isinstance(msg_id, str):
            attr = f"MAVLINK_MSG_ID_{msg_id.upper()}"
            if not hasattr(self._mu.mavlink, attr):
                raise ValueError(f"unknown MAVLink message {msg_id!r}")
            msg_id = int(getattr(self._mu.mavlink, attr))
        self._intervals[int(msg_id)] = float(hz)
        self._send_interval(int(msg_id), float(hz))

    def _target(self) -> tuple[int, int]:
        c = self.config
        auto = self.autopilot or (1, 1)
        return (c.target_system or auto[0], c.target_component or auto[1])

    def _send_interval(self, msg_id: int, hz: float) -> None:
        interval_us = 1e6 / hz if hz > 0 else -1.0
        sysid, compid = self._target()
        self.send(lambda mav: mav.command_long_encode(sysid, compid, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                      float(msg_id), interval_us, 0, 0, 0, 0, 0))

    # the I/O thread
    def _note_error(self, text: str) -> None:
        if text != self._last_error:    # one line per new problem, not one per retry
            log.warning("mavlink %s: %s", self.config.url, text)
            self._last_error = text

    def _connect(self) -> Any:
        c = self.config
        conn = self._mu.mavlink_connection(c.url, baud=c.baud, source_system=c.system_id,
                                           source_component=c.component_id, autoreconnect=False, retries=0)
        port = getattr(conn, "port", None)
        if port is not None and hasattr(port, "write_timeout"):
            port.write_timeout = 0.05      # a full UART buffer must not stall the send clock
        if self._key is not None:
            conn.setup_signing(self._key, sign_outgoing=True)
        return conn

    def _drop(self, why: str) -> None:
        conn, self._conn = self._conn, None
        self._broken = False
        self._note_error(f"link lost ({why}); reconnecting")
        if conn is not None:
            try:
                conn.close()
            except Exception:   # already dead
                pass

    def _io_loop(self) -> None:
        delay = self._backoff[0]
        while not self._stop.is_set():
            if self._conn is None:
                try:
                    conn = self._connect()
                except Exception as exc:   # refused, no device, port in use: retry with back-off
                    self._note_error(f"cannot connect ({type(exc).__name__}: {exc}); retrying in {delay:.1f} s")
                    self._stop.wait(delay)
                    delay = min(delay * 2, self._backoff[1])
                    continue
                delay = self._backoff[0]
                self._conn = conn
                self.connects += 1
                self._last_error = None
                log.info("mavlink %s: connected as system %d component %d", self.config.url,
                         self.config.system_id, self.config.component_id)
                for msg_id, hz in list(self._intervals.items()):
                    self._send_interval(msg_id, hz)
            if self._broken:
                self._drop("write failed")
                continue
            try:
                msgs = self._read(self._conn, 0.1)
            except Exception as exc:   # serial unplugged, socket error
                if self._stop.is_set():    # close() shut the port under us: not a lost link
                    return
                self._drop(f"{type(exc).__name__}: {exc}")
                continue
            for msg in msgs:
                self._dispatch(msg)

    def _read(self, conn: Any, timeout_s: float) -> list[Any]:
        if conn is None:
            return []
        fd = getattr(conn, "fd", None)
        if fd is None:
            self._stop.wait(min(timeout_s, 0.05))
        else:
            readable, _, _ = select.select([fd], [], [], timeout_s)
            if not readable:
                return []
            if isinstance(conn, self._mu.mavtcp):
                try:   # pymavlink only prints on EOF; detect it ourselves
                    if conn.port.recv(1, socket.MSG_PEEK) == b"":
                        raise ConnectionResetError("peer closed the TCP connection")
                except BlockingIOError:
                    return []
        out = []
        with self._lock:
            for _ in range(256):
                msg = conn.recv_msg()
                if msg is None:
                    break
                if msg.get_type() != "BAD_DATA":
                    out.append(msg)
        return out

    def _dispatch(self, msg: Any) -> None:
        self.received += 1
        mtype = msg.get_type()
        if mtype == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID:
            ap = (msg.get_srcSystem(), msg.get_srcComponent())
            if ap != self.autopilot:
                log.info("mavlink: autopilot found: system %d component %d", *ap)
                self.autopilot = ap
                for msg_id, hz in list(self._intervals.items()):
                    self._send_interval(msg_id, hz)
        with self._subs_lock:
            callbacks = list(self._subs.get(mtype, ())) + list(self._subs.get("*", ()))
        for cb in callbacks:
            try:
                cb(msg)
            except Exception:   # a subscriber's bug must not kill the link
                log.exception("mavlink: subscriber for %s failed", mtype)


class SendClock:
    """DISTANCE_SENSOR at ``rate_hz`` and HEARTBEAT at 1 Hz on a thread of its own.

    ``estimate``: returns the newest published estimate (a plain attribute read,
    never a lock the stereo loop holds); ``limits``: the current range limits;
    ``state``: the HEARTBEAT system state (boot, standby, active, critical).
    """

    def __init__(self, link: MavlinkLink, config: MavlinkConfig, max_age_s: float,
                 estimate: Callable[[], Estimate | None], limits: Callable[[], RangeLimits],
                 state: Callable[[], str], clock: Callable[[], float] = time.monotonic):
        self.link = link
        self.config = config
        self.max_age_s = max_age_s
        self.estimate = estimate
        self.limits = limits
        self.state = state
        self.clock = clock
        self.t_start = clock()
        self.orientation = orientation_code(config.orientation)
        self.sensor_type = SENSOR_TYPES[config.sensor_type]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self.valid_sent = 0
        self.last_report: DistanceReport | None = None

    def start(self) -> "SendClock":
        self._thread = threading.Thread(target=self._loop, name="mavlink-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 1.0) -> bool:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def tick(self, now: float) -> DistanceReport:
        report = distance_report(self.estimate(), self.limits(), now, self.max_age_s, self.t_start)
        self.link.distance_sensor(report, self.sensor_type, self.config.sensor_id, self.orientation)
        self.last_report = report
        self.ticks += 1
        self.valid_sent += report.valid
        return report

    def _loop(self) -> None:
        period = 1.0 / self.config.rate_hz
        next_t = self.clock()
        next_hb = next_t
        while not self._stop.wait(max(0.0, next_t - self.clock())):
            now = self.clock()
            try:
                self.tick(now)
                if now >= next_hb:
                    self.link.heartbeat(self.state())
                    next_hb += HEARTBEAT_PERIOD_S
                    if next_hb < now:
                        next_hb = now + HEARTBEAT_PERIOD_S
            except Exception:   # the clock must keep ticking whatever one tick hit
                log.exception("mavlink: send tick failed")
            next_t += period
            if next_t < now - period:   # we were starved: restart the schedule, never send a burst
                next_t = now + period
