"""The daemon's conditions, each with what the wire says in it and what the autopilots then do.

:class:`Condition` is the reason code the service and the send clock act on; its
:class:`ConditionText` (``condition.text``) says it in words: the row of docs/wire.md's
table, which :func:`conditions_table_markdown` writes (``python -m uav_depth.cli.docs
--write``) and tests/test_docs.py checks. Whether a condition sends a DISTANCE_SENSOR
is :attr:`Condition.sends`; :func:`~uav_depth.daemon.link.contract.distance_report`
is the one function that decides it, and tests/daemon/test_link_contract.py drives it
through every condition to hold it to this table.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Condition(str, enum.Enum):
    """What the daemon knows right now; only MEASURING and TOO_CLOSE send a DISTANCE_SENSOR."""

    MEASURING = "measuring"
    TOO_CLOSE = "too close"
    NOTHING_CONFIDENT = "nothing confident"
    STALE = "stale"
    CAMERA_LOST = "camera lost"
    PARAMS_UNUSABLE = "parameters unusable"
    STARTING = "starting"
    SOURCE_ENDED = "source ended"
    SHUTTING_DOWN = "shutting down"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)

    @property
    def sends(self) -> bool:
        """True when a DISTANCE_SENSOR goes out in this condition."""
        return self in (Condition.MEASURING, Condition.TOO_CLOSE)

    @property
    def critical(self) -> bool:
        """True when an active daemon's HEARTBEAT says MAV_STATE_CRITICAL in this condition."""
        return self in (Condition.STALE, Condition.PARAMS_UNUSABLE)

    @property
    def statustext(self) -> tuple[str, str]:
        """(STATUSTEXT, severity) said once when the wire enters this condition."""
        if self is Condition.MEASURING:
            return "uav-depth: measuring", "info"
        if self.sends:
            return f"uav-depth: {self.value}", "warning"
        return f"uav-depth: blind ({self.value})", "warning"

    @property
    def text(self) -> "ConditionText":
        return TEXTS[self]


@dataclass(frozen=True)
class ConditionText:
    """One row of docs/wire.md: when the condition holds, what is sent besides the distance, what each
    autopilot does with it (Markdown)."""

    when: str
    sent: str
    ardupilot: str
    px4: str


_AS_NOTHING = "as \"nothing confident\""

TEXTS: dict[Condition, ConditionText] = {
    Condition.MEASURING: ConditionText(
        "a fresh estimate with a distance within range",
        "`current_distance` = the distance rounded down to the cm; `signal_quality` 2..100; `covariance` = sigma² "
        "in cm² (1..254)",
        "RF: status Good (`AP_RangeFinder_Backend.cpp` `update_status()`: min <= current <= max, inclusive). "
        "PRX-MAV and PRX-RF: an obstacle at that distance in the forward sector; avoidance slows, stops, and backs "
        "away inside `AVOID_MARGIN` (`AC_Avoid.cpp`)",
        "`_addDistanceSensorData()` uses it because current > min (strict); the bins inside `horizontal_fov` hold "
        "the obstacle"),
    Condition.TOO_CLOSE: ConditionText(
        "the ranging says an object is nearer than the minimum range (`Estimate.too_close`), or a reading rounds "
        "to `min_distance` or less",
        "`current_distance` = `min_distance + 1` (the minimum range itself, rounded down); `covariance` 255 "
        "(unknown); `signal_quality` the frame's, or 0 (unknown)",
        "RF: Good (current >= min). PRX-MAV: in range, an obstacle at the floor of the range; PRX-RF: the same. "
        "Avoidance stops and backs away",
        "current > min: an obstacle at the floor of the range; motion toward it is refused"),
    Condition.NOTHING_CONFIDENT: ConditionText(
        "the newest frame measured nothing significant (too few confident pixels, or only farther than the "
        "maximum)",
        "",
        "RF: NoData 500 ms after the last message (`AP_RangeFinder_MAVLink.cpp`, "
        "`AP_RANGEFINDER_MAVLINK_TIMEOUT_MS`); arming fails (\"Rangefinder 1: No Data\"). PRX-MAV: NoData after "
        "500 ms (`PROXIMITY_MAV_TIMEOUT_MS`); PRX-RF: after 200 ms. The last obstacle is held 1-1.75 s "
        "(`PROXIMITY_FACE_RESET_MS` + the 750 ms check), then the face reads empty",
        "the bins age out after 500 ms (`RANGE_STREAM_TIMEOUT_US`) to \"no data\"; motion into a no-data bin "
        "inside the sensor's FOV is refused (`_checkSetpointDirectionFeasability()`, even with `CP_GO_NO_DATA` "
        "1); with no data anywhere the setpoint is zeroed, and after 5 s (`TIMEOUT_HOLD_US`) the vehicle "
        "switches to Hold"),
    Condition.STALE: ConditionText(
        "the newest estimate is older than `ranging.max_age_ms` (the stereo stage is behind or stopped)",
        "HEARTBEAT `system_status` CRITICAL", _AS_NOTHING, _AS_NOTHING),
    Condition.CAMERA_LOST: ConditionText(
        "the source failed or delivered no frame for `service.frame_timeout_s` (the daemon reconnects)",
        "HEARTBEAT CRITICAL; STATUSTEXT \"uav-depth: camera lost\"", _AS_NOTHING, _AS_NOTHING),
    Condition.PARAMS_UNUSABLE: ConditionText(
        "the configured parameter file is missing: the built-in manual defaults run, but they are not what you "
        "set up to fly, so nothing they measure is sent (the file is watched and flies once it appears)",
        "HEARTBEAT CRITICAL; STATUSTEXT \"uav-depth: blind (parameters unusable)\"", _AS_NOTHING, _AS_NOTHING),
    Condition.STARTING: ConditionText(
        "no frame processed yet", "HEARTBEAT BOOT",
        "as \"nothing confident\": the vehicle cannot arm until the daemon measures", _AS_NOTHING),
    Condition.SOURCE_ENDED: ConditionText(
        "a finite source (a replay without `loop`) delivered its last frame; the daemon then stops",
        "HEARTBEAT STANDBY", _AS_NOTHING, _AS_NOTHING),
    Condition.SHUTTING_DOWN: ConditionText(
        "SIGTERM / SIGINT", "STATUSTEXT \"uav-depth: stopping\", then HEARTBEAT POWEROFF", _AS_NOTHING,
        _AS_NOTHING),
}


def conditions_table_markdown() -> str:
    """docs/wire.md's table: one row per :class:`Condition`, in declaration order."""
    rows = ["| condition | when | what is sent | ArduPilot | PX4 |", "|---|---|---|---|---|"]
    for cond in Condition:
        t = cond.text
        sent = t.sent if cond.sends else "; ".join(x for x in ("**nothing**", t.sent) if x)
        rows.append(f"| {cond.value} | {t.when} | {sent} | {t.ardupilot} | {t.px4} |")
    return "\n".join(rows)
