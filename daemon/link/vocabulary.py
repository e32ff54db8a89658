"""MAVLink vocabulary: pymavlink with the MAVLink 2 dialect, the enum values the daemon sends, the cm rules.

Kept apart from the link (:mod:`.endpoint`) so that the config loader can
validate an orientation without importing the link that is built from it.
"""

from __future__ import annotations

import math
import os
from typing import Any

#: Orientation names -> MAV_SENSOR_ORIENTATION. ArduPilot's RNGFND1_ORIENT must hold the same number.
ORIENTATIONS = {"forward": 0, "right": 2, "back": 4, "backward": 4, "left": 6, "up": 24, "down": 25}
SENSOR_TYPES = {"laser": 0, "ultrasound": 1, "infrared": 2, "radar": 3, "unknown": 4}
SEVERITY = {"emergency": 0, "alert": 1, "critical": 2, "error": 3, "warning": 4, "notice": 5, "info": 6,
            "debug": 7}
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
#: HEARTBEAT.autopilot of the two flight stacks whose settings the daemon checks.
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_STATE = {"boot": 1, "standby": 3, "active": 4, "critical": 5, "poweroff": 7}
MAV_CMD_SET_MESSAGE_INTERVAL = 511
UINT8_UNKNOWN = 255
STATUSTEXT_LEN = 50
HEARTBEAT_PERIOD_S = 1.0
#: time_boot_ms is a uint32 of ms: it wraps after 49.7 days.
BOOT_MS_MOD = 1 << 32


def mavutil() -> Any:
    """pymavlink's mavutil with the MAVLink 2 dialect selected.

    pymavlink picks the wire protocol from the MAVLINK20 environment variable when
    a dialect is loaded, so we set it and reload the dialect if another importer
    loaded MAVLink 1 first. MAVLink 2 is needed for signing and the extension
    fields (FOVs, quaternion, signal_quality) of DISTANCE_SENSOR.
    """
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil as mu

    if mu.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        mu.set_dialect(mu.current_dialect)
    return mu


def orientation_code(value: Any) -> int:
    """MAV_SENSOR_ORIENTATION number of a name (forward, down, ...), a rotation name or a number."""
    if isinstance(value, bool):
        raise ValueError("must be an orientation name (forward, back, left, right, up, down) or number")
    if isinstance(value, int):
        if 0 <= value <= 40:
            return value
        raise ValueError("must be a MAV_SENSOR_ORIENTATION number 0..40 (100, custom, needs a quaternion)")
    if isinstance(value, str):
        name = value.strip()
        if name.lower() in ORIENTATIONS:
            return ORIENTATIONS[name.lower()]
        enum = mavutil().mavlink.enums["MAV_SENSOR_ORIENTATION"]
        for code, entry in enum.items():
            if entry.name in (name.upper(), "MAV_SENSOR_ROTATION_" + name.upper()) and code <= 40:
                return code
    raise ValueError("must be forward, back, left, right, up, down, a MAV_SENSOR_ROTATION name (ROLL_180) "
                     "or a number 0..40")


def cm_down(distance_m: float) -> int:
    """A distance in whole cm, rounded down (nearer), never up: 0.2749 m -> 27.

    The 1e-6 cm guard keeps binary floating point from taking 0.29 m (28.999999999999996)
    down to 28.
    """
    return int(math.floor(distance_m * 100.0 + 1e-6))


def wire_range_cm(min_distance_m: float, max_distance_m: float) -> tuple[int, int]:
    """(min_distance, max_distance) in cm on the wire for a sensor's range (m); one rule for every message.

    min_distance is the minimum range rounded down, less 1 cm: every reading (>= the
    minimum, rounded down) is then strictly greater, as PX4 requires, and "too close"
    (min_distance + 1) is the minimum range itself rounded down. max_distance is the
    maximum range rounded down (a reading beyond it is not sent).
    """
    min_cm = max(0, cm_down(min_distance_m) - 1)
    max_cm = max(min_cm + 1, min(65534, cm_down(max_distance_m)))
    return min_cm, max_cm
