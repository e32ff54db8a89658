"""The value rules shared by the parameter schema (:mod:`.params`) and the run config (:mod:`.config`).

One definition of what a number in a YAML file must look like, so the two files
say the same thing in the same words.
"""

from __future__ import annotations

import math
from typing import Any

from uav_depth.core.errors import ConfigError


def fmt(x: float) -> str:
    """A bound as people write it: 16, not 16.0."""
    return str(int(x)) if float(x).is_integer() else str(x)


def number(key: str, value: Any, integer: bool, source: str | None = None) -> int | float:
    """``value`` as an int (``integer``) or a finite float, or a ConfigError naming the key.

    Booleans are not numbers here (YAML's ``yes`` is not 1); 4.0 is accepted as an integer, 4.5 not.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(key, f"must be a number ({'int' if integer else 'float'})", value, source)
    if integer:
        if isinstance(value, float) and not value.is_integer():
            raise ConfigError(key, "must be an integer", value, source)
        return int(value)
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(key, "must be a finite number", value, source)
    return value


def in_range(key: str, value: float, lo: float | None, hi: float | None, source: str | None = None,
             hi_open: bool = False) -> None:
    """Raise unless lo <= value <= hi (value < hi with ``hi_open``); a missing bound is no bound."""
    if lo is not None and hi is not None:
        if not (lo <= value < hi if hi_open else lo <= value <= hi):
            rule = (f"must be at least {fmt(lo)} and below {fmt(hi)}" if hi_open
                    else f"must be between {fmt(lo)} and {fmt(hi)}")
            raise ConfigError(key, rule, value, source)
    elif lo is not None and value < lo:
        raise ConfigError(key, f"must be at least {fmt(lo)}", value, source)
    elif hi is not None and value > hi:
        raise ConfigError(key, f"must be at most {fmt(hi)}", value, source)
