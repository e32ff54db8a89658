"""The runtime's own sections of the run config: ``mavlink``, ``logging`` and ``service``.

Each is a frozen dataclass with its :class:`~uav_depth.core.keys.Key` table (type, bounds,
meaning, extra rule); :mod:`uav_depth.daemon.config` validates the whole run config from
these tables and those of the other parts (ranging, live view, rig check, obstacles, sources).
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uav_depth.core.keys import Key
from uav_depth.daemon.link.vocabulary import orientation_code

_URL_SCHEMES = ("udpout", "udpin", "udp", "tcp", "tcpin")


def _check_url(url: str) -> str | None:
    if url.startswith("/dev/") or re.match(r"^COM\d+$", url):
        return None
    scheme, _, rest = url.partition(":")
    if scheme not in _URL_SCHEMES or not re.match(r"^[^:]+:\d+$", rest):
        return ("must be a pymavlink connection string: udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, "
                "tcpin:HOST:PORT or a serial device (/dev/ttyACM0, with mavlink.baud)")
    port = int(rest.rsplit(":", 1)[1])
    if not 0 < port < 65536:
        return "must name a port between 1 and 65535"
    return None


def _check_ip(value: Any) -> str | None:
    try:
        ipaddress.IPv4Address(value)
    except ValueError:
        return "must be an IPv4 address of this machine (e.g. 192.168.2.10)"
    return None


def _check_orientation(value: Any) -> str | None:
    try:
        orientation_code(value)
    except ValueError as exc:
        return str(exc)
    return None


@dataclass(frozen=True)
class MavlinkConfig:
    """MAVLink 2 output (see :mod:`uav_depth.daemon.link`)."""

    url: str = "udpout:127.0.0.1:14550"
    baud: int = 115200
    rate_hz: float = 20.0
    system_id: int = 1
    component_id: int = 191
    sensor_id: int = 1
    sensor_type: str = "unknown"
    orientation: Any = "forward"
    signing_key_file: Path | None = None
    target_system: int = 0
    target_component: int = 0
    bind_address: str | None = None
    proximity_commit: bool = False

    KEYS = (
        Key("url", "str", "udpout:127.0.0.1:14550", "pymavlink connection string (udpout, udpin, tcp, tcpin, serial)",
            check=_check_url),
        Key("baud", "int", 115200, "serial baud rate (serial devices only)", 1200, 12_000_000),
        Key("rate_hz", "float", 20.0, "most DISTANCE_SENSOR per second: each new estimate is sent as soon as it "
            "exists, so the rate is the stereo rate up to this cap (set it to the camera's frame rate to send every "
            "frame)", 2.0, 200.0),
        Key("system_id", "int", 1, "our MAVLink system id (the vehicle's, so ground stations group us with it)",
            1, 255),
        Key("component_id", "int", 191, "our MAVLink component id (191 = MAV_COMP_ID_ONBOARD_COMPUTER)", 1, 255),
        Key("sensor_id", "int", 1, "DISTANCE_SENSOR.id", 0, 255),
        Key("sensor_type", "str", "unknown", "DISTANCE_SENSOR.type (MAV_DISTANCE_SENSOR)",
            choices=("laser", "ultrasound", "infrared", "radar", "unknown")),
        Key("orientation", "any", "forward", "DISTANCE_SENSOR.orientation: forward, back, left, right, up, down, "
            "a MAV_SENSOR_ROTATION name (ROLL_180) or its number; must match RNGFND1_ORIENT",
            check=_check_orientation, accepts="name, or 0..40"),
        Key("signing_key_file", "path", None, "MAVLink 2 signing key file (64 hex digits, 32 raw bytes, or a "
            "passphrase hashed with SHA-256 as MAVProxy does); must not be readable by group or others",
            optional=True),
        Key("target_system", "int", 0, "the autopilot's system id: commands go to it, and udpin answers only the "
            "address whose HEARTBEAT carries it; 0: the first autopilot HEARTBEAT", 0, 255),
        Key("target_component", "int", 0, "autopilot component id for commands; 0: learn it", 0, 255),
        Key("bind_address", "str", None, "udpout: local address to send from (an interface's address); null: the "
            "address the route to the autopilot uses (127.0.0.1 for a loopback autopilot), never 0.0.0.0",
            optional=True, check=_check_ip),
        Key("proximity_commit", "bool", False, "follow each DISTANCE_SENSOR at once with a copy stamped 1 ms "
            "earlier: ArduPilot's MAVLink proximity backend (PRXn_TYPE 2) holds a reading until a message with "
            "another time_boot_ms arrives, so without the copy avoidance acts on each reading one frame late "
            "(docs/wire.md); on for ArduPilot proximity, harmless elsewhere (twice the messages)"),
    )


@dataclass(frozen=True)
class LoggingConfig:
    """Frame logging for tuning (see :mod:`uav_depth.daemon.framelog`)."""

    dir: Path | None = None
    every_n: int = 10
    max_mb: float = 2000.0
    min_free_mb: float = 500.0
    queue_frames: int = 4

    KEYS = (
        Key("dir", "path", None, "directory that receives one session per run; null disables logging",
            optional=True),
        Key("every_n", "int", 10, "log every Nth processed frame; 0: only on demand (SIGUSR1)", 0, 1_000_000),
        Key("max_mb", "float", 2000.0, "disk budget of the whole directory, MB; oldest sessions are removed first",
            1.0, 10_000_000.0),
        Key("min_free_mb", "float", 500.0, "free-space floor of the log's file system, MB: logging stops (the "
            "daemon flies on) rather than take the disk below it", 0.0, 1.0e9),
        Key("queue_frames", "int", 4, "frames waiting for the writer; more are dropped, never waited for", 1, 1000),
    )


@dataclass(frozen=True)
class ServiceConfig:
    """Lifecycle knobs (see :mod:`uav_depth.daemon.service`)."""

    shutdown_timeout_s: float = 3.0
    frame_timeout_s: float = 2.0
    first_frame_timeout_s: float = 30.0
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 10.0
    status_interval_s: float = 5.0
    stall_timeout_s: float = 10.0
    params_poll_s: float = 1.0
    trial_timeout_s: float = 30.0

    KEYS = (
        Key("shutdown_timeout_s", "float", 3.0, "shutdown gives up on unfinished work after this long", 0.1, 120.0),
        Key("frame_timeout_s", "float", 2.0, "no frame for this long means the camera is lost", 0.05, 120.0),
        Key("first_frame_timeout_s", "float", 30.0, "start-up fails if no frame is processed within this time",
            0.5, 600.0),
        Key("reconnect_min_s", "float", 0.5, "first camera reconnect delay (doubles up to reconnect_max_s)",
            0.01, 60.0),
        Key("reconnect_max_s", "float", 10.0, "longest camera reconnect delay", 0.01, 600.0),
        Key("status_interval_s", "float", 5.0, "period of the status log line and sd_notify STATUS", 0.1, 3600.0),
        Key("stall_timeout_s", "float", 10.0, "one frame in the stereo stage, or one read of the source, for "
            "longer than this is a stall: WATCHDOG=1 stops so systemd can restart", 0.5, 3600.0),
        Key("params_poll_s", "float", 1.0, "parameter file poll period (inotify wakes sooner when available)",
            0.05, 60.0),
        Key("trial_timeout_s", "float", 30.0, "a new parameter set is first run on the test render in a child "
            "process (OpenCV may crash natively on it); a child that has not answered after this long (Python's "
            "start included) is killed and the parameters refused", 1.0, 600.0),
    )
