"""The messages the daemon sends, as builders: ``build(mav) -> message``, run on the link's I/O thread.

A builder is made where the values are known (any thread) and run when the message
is written, with the link's MAVLink object (its sequence numbers and signing).
"""

from __future__ import annotations

from typing import Any, Callable

from uav_depth.daemon.link.contract import DistanceReport
from uav_depth.daemon.link.vocabulary import (MAV_AUTOPILOT_INVALID, MAV_STATE, MAV_TYPE_ONBOARD_CONTROLLER, SEVERITY,
                                              STATUSTEXT_LEN)

Builder = Callable[[Any], Any]


def statustext(text: str, severity: str = "info") -> Builder:
    """STATUSTEXT, cut to 50 characters (the full text goes to the log)."""
    data = text.encode("ascii", "replace")[:STATUSTEXT_LEN]
    level = SEVERITY[severity]
    return lambda mav: mav.statustext_encode(level, data)


def heartbeat(state: str = "active") -> Builder:
    """An onboard controller's HEARTBEAT (MAV_AUTOPILOT_INVALID: not a flight controller) in ``state``."""
    status = MAV_STATE[state]
    return lambda mav: mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, status)


def distance_sensor(r: DistanceReport, sensor_type: int, sensor_id: int, orientation: int) -> Builder:
    """The DISTANCE_SENSOR of a report that sends one (see :func:`~.contract.distance_report`)."""
    if r.current_distance is None:
        raise ValueError(f"a blind report ({r.condition}) sends nothing")
    return lambda mav: mav.distance_sensor_encode(
        r.time_boot_ms, r.min_distance, r.max_distance, r.current_distance, sensor_type, sensor_id, orientation,
        r.covariance, horizontal_fov=r.horizontal_fov, vertical_fov=r.vertical_fov,
        quaternion=(0.0, 0.0, 0.0, 0.0), signal_quality=r.signal_quality)


def param_request_read(target: tuple[int, int], name: str) -> Builder:
    """PARAM_REQUEST_READ of parameter ``name`` (by name: index -1)."""
    sysid, compid = target
    raw = name.encode("ascii")[:16]
    return lambda mav: mav.param_request_read_encode(sysid, compid, raw, -1)


def timesync_request(ts1: int) -> Builder:
    """A TIMESYNC request (tc1 0): ArduPilot and PX4 answer it on the same link with ts1 echoed."""
    return lambda mav: mav.timesync_encode(0, ts1)
