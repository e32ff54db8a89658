"""The autopilot's settings the readings depend on: one rule per parameter, for ArduPilot and PX4 (pure).

Each :class:`Rule` is the one definition of what a parameter must be for the range the
daemon states on the wire (:class:`WireRange`, from ``min_distance`` / ``max_distance``
of docs/wire.md) to be used as sent. The same rules decide what the running daemon
reports after reading the autopilot's values (:mod:`.settings_check`) and what
``uav-depth autopilot-params`` prints to set. Why each rule (ArduPilot 4.7, observed on
SITL; docs/wire.md, "Autopilot settings"):

- ArduPilot's rangefinder clamps the message's range to ``RNGFND1_MIN`` / ``_MAX``: a
  reading below ``RNGFND1_MIN`` is "out of range low" (the proximity library drops it:
  clear), so the minimum must be at or below the daemon's ``min_distance``; a reading
  above ``RNGFND1_MAX`` is "out of range high", so the maximum must be at or above its
  ``max_distance``. ``RNGFND1_ORIENT`` must equal the message's orientation, or every
  message is ignored.
- The proximity backends drop readings outside ``PRX1_MIN`` / ``PRX1_MAX`` (0: no limit).
- Avoidance (``AVOID_MARGIN``; PX4's ``CP_DIST``) must keep the vehicle farther than the
  daemon's "too close" value (``min_distance + 1``, which stands for everything nearer),
  and nearer than its ``max_distance`` (it cannot stop for what it does not see).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

from uav_depth.daemon.link.vocabulary import MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4

#: ArduPilot stores parameters as float32: a value set to 0.23 reads back 0.2300000042.
FLOAT_SLACK = 1e-4
#: The margin ``autopilot-params`` suggests, inside the range (the walk-through's 1.5 m).
MARGIN_M = 1.5
#: PRX1_TYPE values that take the daemon's readings: 2 MAVLink, 4 from the RNGFND1 rangefinder.
PROXIMITY_TYPES = (2, 4)


@dataclass(frozen=True)
class WireRange:
    """What the daemon states on the wire: ``min_cm`` / ``max_cm`` (DISTANCE_SENSOR min/max_distance) and the
    orientation (MAV_SENSOR_ORIENTATION)."""

    min_cm: int
    max_cm: int
    orientation: int

    @property
    def min_m(self) -> float:
        return self.min_cm / 100.0

    @property
    def max_m(self) -> float:
        return self.max_cm / 100.0

    @property
    def floor_m(self) -> float:
        """The "too close" value (``min_distance + 1``): what every nearer object reads as."""
        return (self.min_cm + 1) / 100.0

    def margin(self) -> float:
        """A stopping margin inside the range (:data:`MARGIN_M`, or the middle of a short range)."""
        return MARGIN_M if self.floor_m < MARGIN_M < self.max_m else round((self.floor_m + self.max_m) / 2, 2)


Values = Mapping[str, float]


@dataclass(frozen=True)
class Rule:
    """What parameter ``param`` must be: ``fits(value, range, all values)``; ``value(range)`` to set;
    ``must`` (range) says it in words; ``applies(values)``: whether the rule matters with the other values;
    ``after_reboot``: the parameter exists only once ``RNGFND1_TYPE`` is 10 and the autopilot rebooted."""

    param: str
    fits: Callable[[float, WireRange, Values], bool]
    value: Callable[[WireRange], float]
    must: Callable[[WireRange], str]
    applies: Callable[[Values], bool] = lambda v: True
    after_reboot: bool = False

    def misfit(self, values: Values, rng: WireRange) -> str | None:
        """One line when the autopilot's value does not fit (None: fits, unknown, or does not apply)."""
        v = values.get(self.param)
        if v is None or not self.applies(values) or self.fits(v, rng, values):
            return None
        return f"{self.param} is {v:g}; it must be {self.must(rng)}"


def _rangefinder(v: Values) -> bool:
    return v.get("RNGFND1_TYPE") == 10


def _proximity(v: Values) -> bool:
    return v.get("PRX1_TYPE") in PROXIMITY_TYPES


def _avoiding(v: Values) -> bool:
    return _proximity(v) and int(v.get("AVOID_ENABLE", 0)) & 2 != 0


ARDUPILOT: tuple[Rule, ...] = (
    Rule("RNGFND1_TYPE", lambda x, r, v: x == 10 or v.get("PRX1_TYPE") == 2, lambda r: 10,
         lambda r: "10 (MAVLink), unless PRX1_TYPE is 2: otherwise no reading is used"),
    Rule("PRX1_TYPE", lambda x, r, v: x in PROXIMITY_TYPES or not int(v.get("AVOID_ENABLE", 0)) & 2, lambda r: 2,
         lambda r: "2 (MAVLink) or 4 (from RNGFND1) for avoidance to act on the readings"),
    Rule("RNGFND1_ORIENT", lambda x, r, v: x == r.orientation, lambda r: r.orientation,
         lambda r: f"{r.orientation} (mavlink.orientation): other orientations are ignored", _rangefinder, True),
    Rule("RNGFND1_MIN", lambda x, r, v: x <= r.min_m + FLOAT_SLACK, lambda r: r.min_m,
         lambda r: f"at or below the daemon's min_distance {r.min_m:.2f} m: nearer readings read as out of range "
                   "low (clear)", _rangefinder, True),
    Rule("RNGFND1_MAX", lambda x, r, v: x >= r.max_m - FLOAT_SLACK, lambda r: r.max_m,
         lambda r: f"at or above the daemon's max_distance {r.max_m:.2f} m", _rangefinder, True),
    Rule("RNGFND1_MIN_CM", lambda x, r, v: x <= r.min_cm, lambda r: r.min_cm,
         lambda r: f"at or below {r.min_cm} (older firmware, cm)", _rangefinder, True),
    Rule("RNGFND1_MAX_CM", lambda x, r, v: x >= r.max_cm, lambda r: r.max_cm,
         lambda r: f"at or above {r.max_cm} (older firmware, cm)", _rangefinder, True),
    Rule("PRX1_MIN", lambda x, r, v: x == 0 or x <= r.min_m + FLOAT_SLACK, lambda r: 0.0,
         lambda r: f"0 or at most {r.min_m:.2f} m: the proximity library drops nearer readings", _proximity),
    Rule("PRX1_MAX", lambda x, r, v: x == 0 or x >= r.max_m - FLOAT_SLACK, lambda r: 0.0,
         lambda r: f"0 or at least {r.max_m:.2f} m", _proximity),
    Rule("AVOID_ENABLE", lambda x, r, v: int(x) & 2 != 0, lambda r: 3,
         lambda r: "a value with bit 2 (proximity) set, e.g. 3: avoidance ignores the readings otherwise",
         _proximity),
    Rule("AVOID_MARGIN", lambda x, r, v: r.floor_m < x < r.max_m, lambda r: r.margin(),
         lambda r: f"above {r.floor_m:.2f} m (the too-close value) and below {r.max_m:.2f} m (max_distance)",
         _avoiding),
    Rule("PRX_FILT", lambda x, r, v: x == 0, lambda r: 0.0,
         lambda r: "0: its low-pass holds the obstacle up to 1.3 m behind a 2 m/s approach", _proximity),
)

PX4: tuple[Rule, ...] = (
    Rule("CP_DIST", lambda x, r, v: r.floor_m < x < r.max_m, lambda r: r.margin(),
         lambda r: f"above {r.floor_m:.2f} m (the too-close value) and below {r.max_m:.2f} m (max_distance); "
                   "below 0 turns Collision Prevention off"),
    Rule("CP_GO_NO_DATA", lambda x, r, v: x == 0, lambda r: 0,
         lambda r: "0: with 1 the vehicle may move where no sensor sees"),
)

#: Rule sets by MAV_AUTOPILOT and by the name ``autopilot-params --autopilot`` takes.
RULES: dict[int, tuple[Rule, ...]] = {MAV_AUTOPILOT_ARDUPILOTMEGA: ARDUPILOT, MAV_AUTOPILOT_PX4: PX4}
STACKS: dict[str, int] = {"ardupilot": MAV_AUTOPILOT_ARDUPILOTMEGA, "px4": MAV_AUTOPILOT_PX4}
#: Older firmware's names: asked for too, and shown only when the autopilot has them.
LEGACY = ("RNGFND1_MIN_CM", "RNGFND1_MAX_CM")


def misfits(rules: tuple[Rule, ...], values: Values, rng: WireRange) -> list[str]:
    """One line for each parameter whose value does not fit ``rng``."""
    return [line for rule in rules if (line := rule.misfit(values, rng)) is not None]


def recommended(rules: tuple[Rule, ...], rng: WireRange) -> list[tuple[Rule, float, str]]:
    """(rule, value to set, why) for each rule, older firmware's names left out."""
    return [(r, r.value(rng), r.must(rng)) for r in rules if r.param not in LEGACY]
