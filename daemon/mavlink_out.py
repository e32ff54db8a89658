"""MAVLink 2 output: the wire contract, the link to the autopilot and the send clock.

The wire contract (:func:`distance_report`, documented in docs/wire.md) says, for
each condition of the daemon, what DISTANCE_SENSOR carries. Only two conditions
send one: *measuring* (current = the reading rounded down to the cm, never
farther) and *too close* (current = ``min_distance + 1``, the nearest value both
ArduPilot and PX4 read as an obstacle). Every blind condition (nothing confident,
stale, camera lost, parameters unusable, starting, shutting down) sends **no**
DISTANCE_SENSOR: both autopilots then time out to "no data" (ArduPilot after
500 ms, PX4 after 500 ms); a value outside min..max would read as "clear".
``min_distance`` is the minimum range rounded down, less 1 cm, so a reading at the
minimum is strictly above it (PX4 drops ``current <= min``); ``time_boot_ms`` is
the measurement's capture time (CLOCK_MONOTONIC: time since the companion booted),
so it is strictly increasing from one reading to the next. With ``mavlink.proximity_commit``
each reading is followed at once by one copy stamped 1 ms earlier (ArduPilot's MAVLink
proximity backend applies a reading only when a message with another stamp arrives).

:class:`MavlinkLink` owns the transport (:mod:`.mavlink_transport`) on one I/O
thread: it connects and reconnects (at most every 0.25 s), reads a bounded amount
per turn and hands messages to subscribers, and writes the send queue. The queue is
bounded and droppable: a newer message of a kind replaces an unsent older one, and a
message is stamp-checked at the moment of writing (never written after its
deadline). On TCP the link also proves that the peer is reading (TIMESYNC requests,
which ArduPilot and PX4 answer) and holds measurements back while it is not.

:class:`SendClock` sends each new estimate as soon as it exists (at most
``mavlink.rate_hz`` per second), HEARTBEAT at 1 Hz, and a STATUSTEXT when the wire
condition changes.

Longer than 400 lines because the wire contract, the send clock and the link share one state; splitting the contract out is the next step.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import logging
import math
import os
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.mavlink_enums import (HEARTBEAT_PERIOD_S, MAV_AUTOPILOT_INVALID, MAV_CMD_SET_MESSAGE_INTERVAL,
                                            MAV_STATE, MAV_TYPE_ONBOARD_CONTROLLER, SENSOR_TYPES, SEVERITY,
                                            STATUSTEXT_LEN, UINT8_UNKNOWN, cm_down, mavutil, orientation_code,
                                            wire_range_cm)
from uav_depth.core.errors import ConfigError
from uav_depth.daemon.mavlink_transport import (Stream, TcpClient, TcpServer, Transport, UdpIn, open_transport,
                                                wait_readable)
from uav_depth.daemon.ranging import Estimate, RangeLimits

log = logging.getLogger("uav_depth.mavlink")

#: A key file holds 64 hex digits, 32 bytes or a passphrase: anything larger is not a key file.
KEY_FILE_MAX_BYTES = 4096


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
    if not stat.S_ISREG(st.st_mode) or st.st_size > KEY_FILE_MAX_BYTES:
        raise ConfigError(key, f"must be a regular file of at most {KEY_FILE_MAX_BYTES} bytes",
                          f"{path} ({st.st_size} bytes)")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(KEY_FILE_MAX_BYTES)
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



# -- the wire contract (pure) ------------------------------------------------------------------

MEASURING = "measuring"
TOO_CLOSE = "too close"
NOTHING_CONFIDENT = "nothing confident"
STALE = "stale"
CAMERA_LOST = "camera lost"
PARAMS_UNUSABLE = "parameters unusable"
STARTING = "starting"
SOURCE_ENDED = "source ended"
SHUTTING_DOWN = "shutting down"
#: The conditions that send a DISTANCE_SENSOR; every other one sends none.
SENDING = (MEASURING, TOO_CLOSE)
#: A STATUSTEXT per condition change, at most this often.
STATUSTEXT_MIN_S = 1.0

#: The queue kind of ``mavlink.proximity_commit``'s copy: it replaces an unsent older copy, never a reading.
COMMIT_KIND = "DISTANCE_SENSOR commit"


def boot_ms(t: float, t_start: float = 0.0) -> int:
    """time_boot_ms of monotonic time ``t``: ms since ``t_start`` (0: since the companion booted)."""
    return int(math.floor((t - t_start) * 1000.0)) & 0xFFFFFFFF


@dataclass(frozen=True)
class DistanceReport:
    """What the wire says in one condition: the DISTANCE_SENSOR fields (cm, rad), or nothing.

    ``current_distance`` is None when nothing is sent (every blind condition);
    ``time_boot_ms`` is the measurement's capture time.
    """

    condition: str
    time_boot_ms: int
    min_distance: int
    max_distance: int
    current_distance: int | None
    covariance: int
    signal_quality: int
    horizontal_fov: float
    vertical_fov: float
    age_ms: float | None

    @property
    def sent(self) -> bool:
        return self.current_distance is not None

    @property
    def valid(self) -> bool:
        """A measured distance (not "too close", not blind)."""
        return self.condition == MEASURING


def _quality(q: int) -> int:
    """signal_quality on the wire: 2..100, or 0 (unknown). Never 1 ("invalid"): both autopilots would
    still use the distance, so a distance we send is never labelled invalid."""
    return int(min(100, q)) if q >= 2 else 0


def distance_report(estimate: Estimate | None, limits: RangeLimits, now: float, max_age_s: float,
                    t_start: float = 0.0, blind: str | None = None) -> DistanceReport:
    """The wire contract: what to send at monotonic time ``now`` for the newest ``estimate``.

    ``blind``: a condition the service knows of (camera lost, parameters unusable,
    starting, shutting down) that overrides the estimate. ``limits``: the range
    limits when there is no estimate (an estimate carries those of the parameters
    that measured it).
    """
    if estimate is not None:
        limits = estimate.limits
    min_cm, max_cm = wire_range_cm(limits.min_distance_m, getattr(limits, "stated_max_m", limits.max_distance_m))
    age = None if estimate is None else now - estimate.t_capture
    stamp = boot_ms(estimate.t_capture if estimate is not None else now, t_start)

    def report(condition: str, current: int | None = None, cov: int = UINT8_UNKNOWN, q: int = 0) -> DistanceReport:
        return DistanceReport(condition, stamp, min_cm, max_cm, current, cov, q, limits.hfov_rad, limits.vfov_rad,
                              None if age is None else age * 1000.0)

    if blind is not None:
        return report(blind)
    if estimate is None:
        return report(STARTING)
    if age > max_age_s:
        return report(STALE)
    m = estimate.measurement
    if getattr(estimate, "too_close", False):
        return report(TOO_CLOSE, min_cm + 1, q=_quality(m.quality))
    if not m.valid:
        return report(NOTHING_CONFIDENT)
    cm = cm_down(m.distance_m)
    if cm > max_cm:          # beyond the range: not a confident "clear" either
        return report(NOTHING_CONFIDENT)
    if cm <= min_cm:         # nearer than the minimum range: the nearest value the autopilots take
        return report(TOO_CLOSE, min_cm + 1, q=_quality(m.quality))
    return report(MEASURING, cm, covariance_cm2(m.sigma_m), max(2, _quality(m.quality)))


def covariance_cm2(sigma_m: float | None) -> int:
    """DISTANCE_SENSOR ``covariance``: the variance in cm^2, 1..254, rounded up (a measured 0.3 cm^2 is 1,
    never 0, "unknown" to some readers); 255 (unknown) when there is no sigma or it is larger than the
    field can carry (15.9 cm): never a smaller, more precise-looking value."""
    if sigma_m is None or not math.isfinite(sigma_m):
        return UINT8_UNKNOWN
    cov = max(1, math.ceil((sigma_m * 100.0) ** 2 - 1e-6))   # - 1e-6: float noise is no extra cm^2
    return cov if cov < UINT8_UNKNOWN else UINT8_UNKNOWN


# -- the link ---------------------------------------------------------------------------------

Callback = Callable[[Any], None]
#: Longest wait between two connection attempts: the peer's return is noticed within it.
RECONNECT_MAX_S = 0.25
#: A TCP peer that has answered TIMESYNC once gets each measurement only after answering a request
#: sent just before it; a request unanswered this long means the peer is not reading: measurements are
#: held back (they would wait in its receive buffer and arrive old).
PROBE_TIMEOUT_S = 0.1
#: A udpin peer silent this long may be replaced by the next autopilot that sends a HEARTBEAT.
PEER_SILENT_S = 3.0
#: Messages waiting to be written, at most (the oldest is dropped first).
QUEUE_MAX = 32
#: Inbound bytes parsed per second, at most (a token bucket with a burst of READ_BURST): well above what
#: an autopilot sends (tens of KB/s with every stream on), and a flood beyond it is left to the kernel,
#: which drops it, instead of taking the CPU from the stereo stage.
READ_RATE = 128 * 1024
READ_BURST = 32 * 1024


@dataclass
class _Out:
    kind: str | None
    build: Callable[[Any], Any]
    deadline: float | None
    probe: int | None = None      # TCP: the TIMESYNC request (ts1) this measurement waits to see answered


class _Capture:
    """pymavlink's MAVLink object writes to a file; this one keeps the bytes."""

    buf = b""

    def write(self, buf: bytes) -> None:
        self.buf = bytes(buf)


class MavlinkLink:
    """One MAVLink 2 link with an I/O thread, subscriptions and never-blocking, deadline-checked sends.

    Thread-safe: ``send``, ``send_measurement``, ``statustext``, ``heartbeat``,
    ``subscribe`` and ``request_message_interval`` may be called from any thread;
    they only queue. Subscriber callbacks run on the I/O thread and must return quickly.
    """

    def __init__(self, config: MavlinkConfig, reconnect_min_s: float = 0.05, reconnect_max_s: float = RECONNECT_MAX_S,
                 clock: Callable[[], float] = time.monotonic):
        self.config = config
        self._mu = mavutil()
        self._key = load_signing_key(config.signing_key_file) if config.signing_key_file else None
        self._tx = self._mavlink()
        self._rx = self._mavlink()
        self._t: Transport | None = None
        self._clock = clock
        self._queue: collections.deque[_Out] = collections.deque()
        self._qlock = threading.Lock()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._subs: dict[str, list[Callback]] = {}
        self._subs_lock = threading.Lock()
        self._intervals: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._backoff = (min(reconnect_min_s, RECONNECT_MAX_S), min(max(reconnect_min_s, reconnect_max_s),
                                                                   RECONNECT_MAX_S))
        self._rx_tokens, self._rx_t = float(READ_BURST), clock()
        self._probe: tuple[int, float] | None = None      # (ts1, sent at) of the unanswered TIMESYNC request
        self._peer_answers = False                        # the stream peer has answered a TIMESYNC request
        self._answered = 0                                # ts1 of the newest answered request
        self.autopilot: tuple[int, int] | None = None
        self.sent = 0
        self.dropped = 0          # queued but not written: no connection or peer, queue full, replaced
        self.expired = 0          # not written because its deadline had passed
        self.held = 0             # measurements held back: the TCP peer was not reading
        self.discards = 0         # times the kernel's unsent bytes were thrown away (they had expired)
        self.received = 0
        self.bad = 0              # bytes the parser could not use (BAD_DATA), in messages
        self.connects = 0
        self._last_error: str | None = None

    def _mavlink(self) -> Any:
        mav = self._mu.mavlink.MAVLink(_Capture(), self.config.system_id, self.config.component_id)
        mav.robust_parsing = True
        if self._key is not None:
            mav.signing.secret_key = self._key
            mav.signing.sign_outgoing = True
            mav.signing.link_id = 0
            mav.signing.timestamp = int((max(time.time(), 1420070400) - 1420070400) * 100_000)   # 10 us since 2015
        return mav

    # lifecycle
    def start(self) -> "MavlinkLink":
        if self._thread is None:
            self._thread = threading.Thread(target=self._io_loop, name="mavlink-io", daemon=True)
            self._thread.start()
        return self

    def close(self, timeout_s: float = 1.0) -> bool:
        """Write what is queued (still within its deadline), stop the I/O thread, close; False if it hung."""
        self._stop.set()
        self._wake()
        done = True
        if self._thread is not None:
            self._thread.join(timeout_s)
            done = not self._thread.is_alive()
        if self._thread is None or done:
            self._close_transport()
        return done

    def _close_transport(self) -> None:
        t, self._t = self._t, None
        if t is not None:
            try:
                t.close()
            except OSError:   # closing a dead port must not fail a shutdown
                pass

    @property
    def alive(self) -> bool:
        """The I/O thread runs (it ends only on close, or by dying: then nothing is ever written)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def connected(self) -> bool:
        return self._t is not None

    @property
    def description(self) -> str:
        t = self._t
        return t.description if t is not None else self.config.url

    def wait_connected(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while self._t is None and time.monotonic() < deadline and not self._stop.is_set():
            time.sleep(0.01)
        return self._t is not None

    # sending (queue only; the I/O thread writes)
    def send(self, build: Callable[[Any], Any], kind: str | None = None, deadline: float | None = None) -> bool:
        """Queue ``build(mav)`` for writing; False (and counted) when there is no connection.

        ``kind``: a newer message of the same kind replaces an unsent older one.
        ``deadline``: monotonic s after which the message is never written.
        """
        if self._t is None or self._stop.is_set() and self._thread is None:
            self.dropped += 1
            return False
        with self._qlock:
            if kind is not None:
                for i, o in enumerate(self._queue):
                    if o.kind == kind:
                        del self._queue[i]
                        self.dropped += 1
                        break
            if len(self._queue) >= QUEUE_MAX:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(_Out(kind, build, deadline))
        self._wake()
        return True

    def send_measurement(self, kind: str, build: Callable[[Any], Any], t_capture: float, max_age_s: float) -> bool:
        """Queue a measurement message (DISTANCE_SENSOR, OBSTACLE_DISTANCE...) captured at ``t_capture``.

        It is written only while younger than ``max_age_s`` and, on TCP, only while the
        peer is reading; a newer one of the same ``kind`` replaces it.
        """
        return self.send(build, kind=kind, deadline=t_capture + max_age_s)

    def statustext(self, text: str, severity: str = "info") -> bool:
        """Send a STATUSTEXT (cut to 50 characters; the full text goes to the log)."""
        data = text.encode("ascii", "replace")[:STATUSTEXT_LEN]
        return self.send(lambda mav: mav.statustext_encode(SEVERITY[severity], data))

    def heartbeat(self, state: str = "active") -> bool:
        return self.send(lambda mav: mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID,
                                                          0, 0, MAV_STATE[state]), kind="HEARTBEAT")

    def distance_sensor(self, r: DistanceReport, sensor_type: int, sensor_id: int, orientation: int,
                        t_capture: float, max_age_s: float, kind: str = "DISTANCE_SENSOR") -> bool:
        """Queue the DISTANCE_SENSOR of a report that sends one (see :func:`distance_report`).

        ``kind``: what a newer message replaces while this one waits (:data:`COMMIT_KIND` for the
        proximity commit copy, so that it never replaces the reading it follows).
        """
        assert r.current_distance is not None, "a blind report sends nothing"
        return self.send_measurement(kind, lambda mav: mav.distance_sensor_encode(
            r.time_boot_ms, r.min_distance, r.max_distance, r.current_distance, sensor_type, sensor_id,
            orientation, r.covariance, horizontal_fov=r.horizontal_fov, vertical_fov=r.vertical_fov,
            quaternion=(0.0, 0.0, 0.0, 0.0), signal_quality=r.signal_quality), t_capture, max_age_s)

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"\0")
        except (BlockingIOError, OSError):   # already awake (pipe full) or closed
            pass

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

    def _new_connection(self) -> None:
        self._rx = self._mavlink()
        self._probe, self._peer_answers, self._answered = None, False, 0
        for msg_id, hz in list(self._intervals.items()):
            self._send_interval(msg_id, hz)

    def _drop(self, why: str) -> None:
        self._close_transport()
        self._note_error(f"link lost ({why}); reconnecting")

    def _io_loop(self) -> None:
        delay = self._backoff[0]
        while True:
            if self._stop.is_set():
                if self._t is not None:
                    try:
                        self._write_queue(self._clock())    # the last words (STATUSTEXT, HEARTBEAT poweroff)
                    except (ConnectionError, OSError):
                        pass
                return
            if self._t is None:
                try:
                    t = open_transport(self.config.url, self.config.baud, self.config.bind_address)
                except (OSError, ValueError, ConnectionError) as exc:   # refused, no device, port in use
                    self._note_error(f"cannot connect ({type(exc).__name__}: {exc}); retrying in {delay:.2f} s")
                    self._stop.wait(delay)
                    delay = min(delay * 2, self._backoff[1])
                    continue
                delay = self._backoff[0]
                self._t = t
                self.connects += 1
                self._last_error = None
                log.info("mavlink %s: connected (%s) as system %d component %d", self.config.url, t.description,
                         self.config.system_id, self.config.component_id)
                self._new_connection()
            try:
                self._turn(self._t)
            except (ConnectionError, OSError) as exc:   # serial unplugged, socket error, peer gone
                if self._stop.is_set():
                    continue
                self._drop(f"{type(exc).__name__}: {exc}")

    def _turn(self, t: Transport) -> None:
        """One turn: accept, write the queue, check the kernel's backlog, read a bounded amount."""
        t.poll()
        if isinstance(t, TcpServer) and t.new_connection():
            log.info("mavlink %s: peer connected", self.config.url)
            self._new_connection()
        now = self._clock()
        self._write_queue(now)
        if isinstance(t, Stream) and t.overdue(now):
            t.discard()          # what the kernel still holds has expired: it must not arrive
            self.discards += 1
            self._note_error("peer not taking data: unsent messages expired and were discarded")
        if isinstance(t, UdpIn) and t.peer is not None and now - t.peer_heard > PEER_SILENT_S:
            log.warning("mavlink %s: autopilot at %s:%d silent for %.0f s; waiting for its HEARTBEAT",
                        self.config.url, t.peer[0], t.peer[1], PEER_SILENT_S)
            t.peer = None
        if t.dead:
            raise ConnectionError("connection reset")
        with self._qlock:
            pending = any(o.probe is None for o in self._queue)   # waiting for an answer: the socket wakes us
        self._rx_tokens = min(float(READ_BURST), self._rx_tokens + (now - self._rx_t) * READ_RATE)
        self._rx_t = now
        reading = self._rx_tokens > 0              # over the inbound budget: the kernel holds (or drops) it
        fds = [t.fileno(), self._wake_r] if reading else [self._wake_r]
        ready = wait_readable(fds, 0.0 if pending else (0.05 if reading else 0.02))
        if self._wake_r in ready:
            try:
                os.read(self._wake_r, 4096)
            except BlockingIOError:
                pass
        if reading and t.fileno() in ready:
            self._rx_tokens -= self._read(t)

    def _ask(self, t: Transport, now: float) -> int | None:
        """Send a TIMESYNC request (tc1 0); ArduPilot and PX4 answer it on the same link."""
        ts1 = time.monotonic_ns()
        if not t.write(self._tx.timesync_encode(0, ts1).pack(self._tx)):
            return None
        self._tx.seq = (self._tx.seq + 1) % 256
        self._probe = (ts1, now)
        return ts1

    def _write_queue(self, now: float) -> None:
        t = self._t
        if t is None:
            return
        with self._qlock:
            items = list(self._queue)
            self._queue.clear()
        probe = isinstance(t, (TcpClient, TcpServer))
        waiting: list[_Out] = []
        for o in items:
            if o.deadline is not None and now > o.deadline:
                self.expired += 1
                continue
            if not t.can_send:
                self.dropped += 1
                continue
            if o.deadline is not None and probe and self._peer_answers:
                # Ask first, write after the answer: a peer answers only while its application reads, so
                # what follows an answer is read at once, and a peer that stopped reading is written nothing
                # that would wait in its receive buffer and arrive old.
                if o.probe is None:
                    if self._probe is not None and now - self._probe[1] >= PROBE_TIMEOUT_S:
                        self.held += 1                        # not reading: held back, not queued
                        if now - self._probe[1] > 1.0:
                            self._ask(t, now)                 # ask again now and then
                        continue
                    o.probe = self._probe[0] if self._probe is not None else self._ask(t, now)
                    if o.probe is None:
                        self.dropped += 1
                        continue
                if self._answered < o.probe:
                    if self._probe is None or self._probe[0] != o.probe or now - self._probe[1] >= PROBE_TIMEOUT_S:
                        self.held += 1
                    else:
                        waiting.append(o)
                    continue
            msg = o.build(self._tx)
            buf = msg.pack(self._tx)
            self._tx.seq = (self._tx.seq + 1) % 256
            if t.write(buf, o.deadline):
                self.sent += 1
            else:
                self.dropped += 1
                continue
            if o.deadline is not None and probe and not self._peer_answers and (
                    self._probe is None or now - self._probe[1] > 1.0):
                self._ask(t, now)                             # does this peer answer? then it is gated
        if waiting:
            with self._qlock:
                kinds = {o.kind for o in self._queue}
                self._queue.extendleft(o for o in reversed(waiting) if o.kind not in kinds)

    def _read(self, t: Transport) -> int:
        """Parse what is there (bounded by the transport's read budget); the number of bytes read."""
        got = t.read()
        for data, addr in got:
            if isinstance(t, UdpIn) and t.peer is None:
                self._bind_udpin(t, data, addr)
                continue
            for msg in self._rx.parse_buffer(data) or ():
                if msg.get_type() == "BAD_DATA":
                    self.bad += 1
                    continue
                self._dispatch(msg)
        return sum(len(data) for data, _ in got)

    def _is_our_autopilot(self, msg: Any) -> bool:
        want = self.config.target_system
        return (msg.get_type() == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID
                and (not want or msg.get_srcSystem() == want))

    def _bind_udpin(self, t: UdpIn, data: bytes, addr: Any) -> None:
        """udpin answers one autopilot: the first to send a HEARTBEAT (of ``target_system`` if set)."""
        scan = self._mavlink()
        for msg in scan.parse_buffer(data) or ():
            if msg.get_type() != "BAD_DATA" and self._is_our_autopilot(msg):
                t.bind_peer(addr)
                log.info("mavlink %s: answering the autopilot at %s:%d (system %d) only", self.config.url,
                         addr[0], addr[1], msg.get_srcSystem())
                self._new_connection()
                self._dispatch(msg)
                return

    def _dispatch(self, msg: Any) -> None:
        self.received += 1
        mtype = msg.get_type()
        if mtype == "TIMESYNC" and msg.tc1 != 0:
            if self._probe is not None and msg.ts1 == self._probe[0]:
                self._answered, self._probe, self._peer_answers = msg.ts1, None, True
        elif self._is_our_autopilot(msg):
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
    """Sends each new estimate as soon as it exists, HEARTBEAT at 1 Hz, STATUSTEXT on condition changes.

    ``estimate``: returns the newest published estimate (a plain attribute read,
    never a lock the stereo loop holds); :meth:`notify` wakes the clock when one is
    published (until it is first called, the clock looks every 10 ms; then every 100 ms and on each
    notify). ``limits``: the current
    range limits; ``state``: the HEARTBEAT system state (boot, standby, active,
    critical, poweroff), for HEARTBEAT alone; ``blind``: the blind condition the service is in
    (its one condition: :attr:`uav_depth.daemon.service.Service.condition`), or None while it measures.

    Each estimate is sent at most once, with time_boot_ms = its capture time; an
    estimate not newer than the last one sent is never sent; at most
    ``mavlink.rate_hz`` DISTANCE_SENSOR per second (a newer estimate replaces one
    waiting for its slot). Blind: nothing is sent. ``mavlink.proximity_commit``: each
    reading sent is followed by its copy stamped 1 ms earlier (not counted in ``ticks``).
    """

    def __init__(self, link: MavlinkLink, config: MavlinkConfig, max_age_s: float,
                 estimate: Callable[[], Estimate | None], limits: Callable[[], RangeLimits],
                 state: Callable[[], str], clock: Callable[[], float] = time.monotonic,
                 blind: Callable[[], str | None] | None = None):
        self.link = link
        self.config = config
        self.max_age_s = max_age_s
        self.estimate = estimate
        self.limits = limits
        self.state = state
        self.blind = blind
        self.clock = clock
        self.t_start = 0.0                 # time_boot_ms counts from the companion's boot (CLOCK_MONOTONIC)
        self.orientation = orientation_code(config.orientation)
        self.sensor_type = SENSOR_TYPES[config.sensor_type]
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._notified = False
        self._thread: threading.Thread | None = None
        self._last_sent: Estimate | None = None
        self._last_stamp = -1
        self._last_send_t = -math.inf
        self._told: str | None = None       # the condition the last STATUSTEXT announced
        self._told_t = -math.inf
        self.ticks = 0                     # DISTANCE_SENSOR sent
        self.valid_sent = 0                # of which measured distances
        self.condition = STARTING
        self.last_report: DistanceReport | None = None
        self.send_latency_ms: collections.deque[float] = collections.deque(maxlen=1000)   # capture -> queued

    def start(self) -> "SendClock":
        self._thread = threading.Thread(target=self._loop, name="mavlink-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 1.0) -> bool:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def notify(self) -> None:
        """A new estimate was published: send it now."""
        self._notified = True
        self._wake.set()

    def blind_condition(self) -> str | None:
        return self.blind() if self.blind is not None else None

    def tick(self, now: float) -> DistanceReport:
        """Evaluate the wire contract now; send the newest estimate if it is new and due."""
        est = self.estimate()
        report = distance_report(est, self.limits(), now, self.max_age_s, self.t_start, self.blind_condition())
        self.condition = report.condition
        self.last_report = report
        if (report.sent and est is not None and est is not self._last_sent
                and report.time_boot_ms > self._last_stamp and now - self._last_send_t >= self._period()):
            self.link.distance_sensor(report, self.sensor_type, self.config.sensor_id, self.orientation,
                                      est.t_capture, self.max_age_s)
            if self.config.proximity_commit and report.time_boot_ms > 0:
                # ArduPilot's MAVLink proximity backend keeps a reading pending until a message with
                # another time_boot_ms arrives: this copy (the same measurement, stamped 1 ms earlier,
                # so never newer than it is) closes it now instead of a frame later.
                self.link.distance_sensor(dataclasses.replace(report, time_boot_ms=report.time_boot_ms - 1),
                                          self.sensor_type, self.config.sensor_id, self.orientation,
                                          est.t_capture, self.max_age_s, kind=COMMIT_KIND)
            self._last_sent, self._last_stamp, self._last_send_t = est, report.time_boot_ms, now
            self.ticks += 1
            self.valid_sent += report.valid
            self.send_latency_ms.append((now - est.t_capture) * 1000.0)
        self._announce(now)
        return report

    def _period(self) -> float:
        return 1.0 / self.config.rate_hz

    def _announce(self, now: float) -> None:
        cond = self.condition
        if cond == self._told or now - self._told_t < STATUSTEXT_MIN_S:
            return
        if cond in SENDING:
            ok = self.link.statustext(f"uav-depth: {cond}", "info" if cond == MEASURING else "warning")
        else:
            ok = self.link.statustext(f"uav-depth: blind ({cond})", "warning")
        if ok:                       # not connected yet: said once the link is up
            self._told, self._told_t = cond, now

    def heartbeat_state(self) -> str:
        state = self.state()
        return "critical" if state == "active" and self.condition in (STALE, PARAMS_UNUSABLE) else state

    def _loop(self) -> None:
        next_hb = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            try:
                self.tick(now)
                if now >= next_hb:
                    self.link.heartbeat(self.heartbeat_state())
                    next_hb = now + HEARTBEAT_PERIOD_S      # late: the next one a period later, never a burst
            except Exception:   # the clock must keep ticking whatever one tick hit
                log.exception("mavlink: send tick failed")
            wait = min(0.1 if self._notified else 0.01, max(0.0, next_hb - now))
            slot = self._last_send_t + self._period() - now
            if slot > 0:
                wait = min(wait, slot)
            self._wake.wait(wait)
            self._wake.clear()
