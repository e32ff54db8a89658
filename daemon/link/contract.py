"""The wire contract (pure): for each condition of the daemon, what DISTANCE_SENSOR carries.

Documented in docs/wire.md, whose table :mod:`.conditions` writes. Only two
conditions send one: *measuring* (current = the reading rounded down to the cm,
never farther) and *too close* (current = ``min_distance + 1``, the nearest value
both ArduPilot and PX4 read as an obstacle). Every blind condition sends **no**
DISTANCE_SENSOR: both autopilots then time out to "no data" after 500 ms; a value
outside min..max would read as "clear". ``min_distance`` is the minimum range
rounded down, less 1 cm, so a reading at the minimum is strictly above it (PX4 drops
``current <= min``); ``time_boot_ms`` is the measurement's capture time
(CLOCK_MONOTONIC: time since the companion booted), a uint32 of ms that wraps
after 49.7 days, so stamps are ordered with serial-number arithmetic
(:func:`stamp_after`), never with ``>``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uav_depth.daemon.link.conditions import Condition
from uav_depth.daemon.link.vocabulary import BOOT_MS_MOD, UINT8_UNKNOWN, cm_down, wire_range_cm
from uav_depth.core.ranging import RangeLimits


from uav_depth.daemon.estimate import Estimate
def boot_ms(t: float, t_start: float = 0.0) -> int:
    """time_boot_ms of monotonic time ``t``: ms since ``t_start`` (0: since the companion booted), mod 2^32."""
    return int(math.floor((t - t_start) * 1000.0)) % BOOT_MS_MOD


def stamp_after(a: int, b: int) -> bool:
    """True when time_boot_ms ``a`` is later than ``b`` (RFC 1982 serial-number arithmetic on 32 bits).

    Right across the wrap (0 comes after 4294967295) as long as the two are less than
    24.8 days apart; one stamp never comes after itself.
    """
    d = (a - b) % BOOT_MS_MOD
    return 0 < d < BOOT_MS_MOD // 2


def stamp_before(a: int, ms: int = 1) -> int:
    """The time_boot_ms ``ms`` earlier than ``a``, across the wrap."""
    return (a - ms) % BOOT_MS_MOD


@dataclass(frozen=True)
class DistanceReport:
    """What the wire says in one condition: the DISTANCE_SENSOR fields (cm, rad), or nothing.

    ``current_distance`` is None when nothing is sent (every blind condition);
    ``time_boot_ms`` is the measurement's capture time.
    """

    condition: Condition
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
        return self.condition is Condition.MEASURING


def _quality(q: int) -> int:
    """signal_quality on the wire: 2..100, or 0 (unknown). Never 1 ("invalid"): both autopilots would
    still use the distance, so a distance we send is never labelled invalid."""
    return int(min(100, q)) if q >= 2 else 0


def covariance_cm2(sigma_m: float | None) -> int:
    """DISTANCE_SENSOR ``covariance``: the variance in cm^2, 1..254, rounded up (a measured 0.3 cm^2 is 1,
    never 0, "unknown" to some readers); 255 (unknown) when there is no sigma or it is larger than the
    field can carry (15.9 cm): never a smaller, more precise-looking value."""
    if sigma_m is None or not math.isfinite(sigma_m):
        return UINT8_UNKNOWN
    cov = max(1, math.ceil((sigma_m * 100.0) ** 2 - 1e-6))   # - 1e-6: float noise is no extra cm^2
    return cov if cov < UINT8_UNKNOWN else UINT8_UNKNOWN


def stated_range_cm(limits: RangeLimits) -> tuple[int, int]:
    """(min_distance, max_distance) in cm that DISTANCE_SENSOR states for ``limits``."""
    return wire_range_cm(limits.min_distance_m, getattr(limits, "stated_max_m", limits.max_distance_m))


def _condition(estimate: Estimate | None, age: float | None, max_age_s: float, blind: Condition | None,
               min_cm: int, max_cm: int) -> tuple[Condition, int | None]:
    """The condition and the distance (cm) it sends, or None."""
    if blind is not None:
        return Condition(blind), None
    if estimate is None:
        return Condition.STARTING, None
    if age > max_age_s:
        return Condition.STALE, None
    m = estimate.measurement
    if getattr(estimate, "too_close", False):
        return Condition.TOO_CLOSE, min_cm + 1
    if not m.valid:
        return Condition.NOTHING_CONFIDENT, None
    cm = cm_down(m.distance_m)
    if cm > max_cm:          # beyond the range: not a confident "clear" either
        return Condition.NOTHING_CONFIDENT, None
    if cm <= min_cm:         # nearer than the minimum range: the nearest value the autopilots take
        return Condition.TOO_CLOSE, min_cm + 1
    return Condition.MEASURING, cm


def distance_report(estimate: Estimate | None, limits: RangeLimits, now: float, max_age_s: float,
                    t_start: float = 0.0, blind: Condition | str | None = None) -> DistanceReport:
    """The wire contract: what to send at monotonic time ``now`` for the newest ``estimate``.

    ``blind``: a condition the service knows of (camera lost, parameters unusable,
    starting, shutting down) that overrides the estimate. ``limits``: the range
    limits when there is no estimate (an estimate carries those of the parameters
    that measured it).
    """
    if estimate is not None:
        limits = estimate.limits
    min_cm, max_cm = stated_range_cm(limits)
    age = None if estimate is None else now - estimate.t_capture
    stamp = boot_ms(estimate.t_capture if estimate is not None else now, t_start)
    cond, current = _condition(estimate, age, max_age_s, None if blind is None else Condition(blind), min_cm,
                               max_cm)
    cov, q = UINT8_UNKNOWN, 0
    if cond is Condition.MEASURING:
        m = estimate.measurement
        cov, q = covariance_cm2(m.sigma_m), max(2, _quality(m.quality))
    elif cond is Condition.TOO_CLOSE:
        q = _quality(estimate.measurement.quality)
    return DistanceReport(cond, stamp, min_cm, max_cm, current, cov, q, limits.hfov_rad, limits.vfov_rad,
                          None if age is None else age * 1000.0)
