"""The link to the autopilot: one MAVLink 2 connection, owned by one I/O thread.

:class:`MavlinkLink` is what the rest of the daemon holds: it queues what is sent
(:mod:`.queue`: bounded, droppable, every message checked against its deadline at the
moment it is written) and hands what is received to subscribers
(:class:`~.inbound.Dispatcher`). Its I/O thread runs a :class:`~.pump.Pump`, which
connects, reconnects, writes and reads. Who it talks to is :mod:`.peers` (the one
udpin owner, the TCP read gate); what it accepts is :mod:`.signing`; the pipes are
:mod:`.transport` and :mod:`.streams`.

Should the I/O thread die, :attr:`MavlinkLink.alive` turns False, and the service's
health check stops feeding systemd's watchdog (systemd restarts the daemon).
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.link import messages
from uav_depth.daemon.link.contract import DistanceReport
from uav_depth.daemon.link.inbound import Callback, Dispatcher
from uav_depth.daemon.link.pump import Pump
from uav_depth.daemon.link.queue import LinkCounters, Out, SendQueue
from uav_depth.daemon.link.signing import Signing, load_signing_key
from uav_depth.daemon.link.vocabulary import mavutil


#: Longest wait between two connection attempts: the peer's return is noticed within it.
RECONNECT_MAX_S = 0.25


class MavlinkLink:
    """One MAVLink 2 link with an I/O thread, subscriptions and never-blocking, deadline-checked sends.

    Thread-safe: ``send``, ``send_measurement``, ``statustext``, ``heartbeat``, ``request_param``,
    ``subscribe`` and ``request_message_interval`` may be called from any thread; they only queue.
    Subscriber callbacks run on the I/O thread and must return quickly.
    """

    def __init__(self, config: MavlinkConfig, reconnect_min_s: float = 0.05, reconnect_max_s: float = RECONNECT_MAX_S,
                 clock: Callable[[], float] = time.monotonic):
        self.config = config
        self._mu = mavutil()
        key = load_signing_key(config.signing_key_file) if config.signing_key_file else None
        self.signing = Signing(self._mu.mavlink, key, config.system_id, config.component_id)
        self._clock = clock
        self.count = LinkCounters()
        self._queue = SendQueue(self.count)
        self._inbound = Dispatcher(self.send, config.target_system, config.target_component)
        lo = min(reconnect_min_s, RECONNECT_MAX_S)
        backoff = (lo, min(max(reconnect_min_s, reconnect_max_s), RECONNECT_MAX_S))
        self._pump = Pump(config, self.signing, self._queue, self.count, self._inbound, backoff, clock)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        #: The check of the autopilot's settings on this link (:func:`.settings_check.attach`), once started.
        self.settings_check: Any = None

    # -- lifecycle and state -------------------------------------------------------------------
    def start(self) -> "MavlinkLink":
        if self._thread is None:
            self._thread = threading.Thread(target=self._pump.run, args=(self._stop,), name="mavlink-io",
                                            daemon=True)
            self._thread.start()
        return self

    def close(self, timeout_s: float = 1.0) -> bool:
        """Write what is queued (still within its deadline), stop the I/O thread, close; False if it hung."""
        self._stop.set()
        self._pump.wake()
        done = True
        if self._thread is not None:
            self._thread.join(timeout_s)
            done = not self._thread.is_alive()
        if self._thread is None or done:
            self._pump.close_transport()
        return done

    @property
    def alive(self) -> bool:
        """True while the I/O thread runs: False before :meth:`start`, after :meth:`close`, and if it died
        (the service's health check then stops feeding the watchdog)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def connected(self) -> bool:
        return self._pump.t is not None

    @property
    def description(self) -> str:
        t = self._pump.t
        return t.description if t is not None else self.config.url

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot heard (its HEARTBEAT), or None."""
        return self._inbound.autopilot

    @property
    def autopilot_type(self) -> int | None:
        """MAV_AUTOPILOT of the autopilot heard (3 ArduPilot, 12 PX4), or None."""
        return self._inbound.autopilot_type

    def autopilot_heard(self, now: float | None = None) -> bool:
        """True while the autopilot's last HEARTBEAT is at most 3 s old."""
        return self._inbound.heard(self._clock() if now is None else now)

    def wait_connected(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while self._pump.t is None and time.monotonic() < deadline and not self._stop.is_set():
            time.sleep(0.01)
        return self._pump.t is not None

    # -- sending (queue only; the I/O thread writes) -------------------------------------------
    def send(self, build: Callable[[Any], Any], kind: str | None = None, deadline: float | None = None,
             tally: tuple[str, ...] = ()) -> bool:
        """Queue ``build(mav)`` for writing; False (and counted) when there is no connection.

        ``kind``: a newer message of the same kind replaces an unsent older one.
        ``deadline``: monotonic s after which the message is never written.
        ``tally``: counters of ``count.delivered`` it adds to when written while an autopilot is heard.
        """
        if self._pump.t is None or self._stop.is_set() and self._thread is None:
            self.count.drop("dropped", Out(kind, build, deadline, tally))
            return False
        self._queue.put(Out(kind, build, deadline, tally))
        self._pump.wake()
        return True

    def send_measurement(self, kind: str, build: Callable[[Any], Any], t_capture: float, max_age_s: float,
                         tally: tuple[str, ...] = ()) -> bool:
        """Queue a measurement (DISTANCE_SENSOR, OBSTACLE_DISTANCE...) captured at ``t_capture``: written only
        while younger than ``max_age_s`` and, on TCP, only to a peer that shows it is reading."""
        return self.send(build, kind=kind, deadline=t_capture + max_age_s, tally=tally)

    def statustext(self, text: str, severity: str = "info") -> bool:
        """Send a STATUSTEXT (cut to 50 characters)."""
        return self.send(messages.statustext(text, severity))

    def heartbeat(self, state: str = "active") -> bool:
        return self.send(messages.heartbeat(state), kind="HEARTBEAT")

    def distance_sensor(self, r: DistanceReport, sensor_type: int, sensor_id: int, orientation: int,
                        t_capture: float, max_age_s: float, kind: str = "DISTANCE_SENSOR",
                        tally: tuple[str, ...] = ()) -> bool:
        """Queue the DISTANCE_SENSOR of a report that sends one; ``kind`` as :meth:`send`."""
        return self.send_measurement(kind, messages.distance_sensor(r, sensor_type, sensor_id, orientation),
                                     t_capture, max_age_s, tally)

    def request_param(self, name: str) -> bool:
        """Ask the autopilot for parameter ``name`` (PARAM_REQUEST_READ); the answer is a PARAM_VALUE."""
        return self.send(messages.param_request_read(self._inbound.target(), name))

    # -- receiving ---------------------------------------------------------------------------------
    def subscribe(self, msg_type: str, callback: Callback) -> Callable[[], None]:
        """Call ``callback(msg)`` on the I/O thread for every incoming ``msg_type`` ("*": all); returns the
        function that removes the subscription."""
        return self._inbound.subscribe(msg_type, callback)

    def request_message_interval(self, msg_id: int | str, hz: float) -> None:
        """Ask the autopilot to stream ``msg_id`` (number or name) at ``hz`` (<= 0 stops it); remembered and
        asked again whenever the link reconnects or a (new) autopilot appears."""
        if isinstance(msg_id, str):
            attr = f"MAVLINK_MSG_ID_{msg_id.upper()}"
            if not hasattr(self._mu.mavlink, attr):
                raise ValueError(f"unknown MAVLink message {msg_id!r}")
            msg_id = int(getattr(self._mu.mavlink, attr))
        self._inbound.request_interval(int(msg_id), float(hz))
