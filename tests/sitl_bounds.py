"""The reading-lag bounds the SITL tests hold the daemon's readings to: one definition.

The lag is a reading (DISTANCE_SENSOR, m) minus the geometry at the instant it is compared: never nearer than
the truth by more than 5 % of 2.5 m and the wire's 1 cm, and never farther than the distance flown since the
frame was captured (``max_age_s``, the oldest reading the daemon may send, plus a pose at most 0.1 s old when
rendered and the trip to the ground station, 0.2 s together, at ``speed_mps``) and the same 5 % and 1 cm.
Used by tests/cli/test_sitl_ardupilot.py (the real ArduCopter SITL) and tests/cli/test_sitl_hover_range.py
(the same scene in process, in CI).
"""

from __future__ import annotations

#: How much nearer than the truth a reading may be, m: 5 % of 2.5 m and the wire's whole centimetre.
NEARER_M = 0.05 * 2.5 + 0.01
#: What a pose may add to a reading's age when it is rendered and delivered, s.
POSE_AND_TRIP_S = 0.2


def reading_lag_bounds(speed_mps: float, max_age_s: float) -> tuple[float, float]:
    """(lowest, highest) reading lag, m, for an approach at ``speed_mps`` with readings up to ``max_age_s`` old."""
    return -NEARER_M, speed_mps * (max_age_s + POSE_AND_TRIP_S) + NEARER_M
