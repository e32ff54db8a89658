"""Config key declarations: one :class:`Key` per key, and the section validator.

Every config section of every room (the run config, each frame source, the
simulator's scene) declares its keys once in a ``KEYS`` table; the loader, the
environment overrides and the docs' reference tables all read those tables.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from uav_depth.core.errors import ConfigError
from uav_depth.core.validate import fmt, in_range, number


@dataclass(frozen=True)
class Key:
    """Declaration of one config key: type, default, bounds, meaning.

    ``kind``: int, float, bool, str, path, roi (four ints x0 y0 x1 y1, px), any.
    ``lo``/``hi`` are inclusive unless ``hi_open`` (value must be below ``hi``).
    ``optional``: null is accepted (and is the default when ``default`` is None).
    ``check``: an extra rule, returning the error text or None.
    """

    name: str
    kind: str
    default: Any
    doc: str
    lo: float | None = None
    hi: float | None = None
    hi_open: bool = False
    choices: tuple[Any, ...] | None = None
    optional: bool = False
    check: Callable[[Any], str | None] | None = None
    accepts: str | None = None       # what the README says the key accepts, when the kind does not say it

    def accepted(self) -> str:
        """Human text of what the key accepts (README table)."""
        if self.accepts:
            text = self.accepts
        elif self.kind == "bool":
            text = "true / false"
        elif self.choices:
            text = " / ".join(str(c) for c in self.choices)
        elif self.kind == "roi":
            text = "[x0, y0, x1, y1] px"
        elif self.lo is not None and self.hi is not None:
            text = f"{fmt(self.lo)}..{fmt(self.hi)}" + (" (exclusive)" if self.hi_open else "")
        elif self.lo is not None:
            text = f">= {fmt(self.lo)}"
        else:
            text = self.kind
        return text + (", or null" if self.optional else "")

    def validate(self, section: str, value: Any, source: str | None) -> Any:
        key = f"{section}.{self.name}" if section else self.name
        if value is None:
            if self.optional:
                return None
            raise ConfigError(key, "is required", None, source)
        kind = self.kind
        if kind == "bool":
            if not isinstance(value, bool):
                raise ConfigError(key, "must be true or false", value, source)
        elif kind in ("int", "float"):
            value = number(key, value, kind == "int", source)
            in_range(key, value, self.lo, self.hi, source, self.hi_open)
        elif kind in ("str", "path"):
            if not isinstance(value, str) or not value:
                raise ConfigError(key, "must be a non-empty string", value, source)
            if kind == "path":
                value = Path(os.path.expanduser(value))
        elif kind == "roi":
            if (not isinstance(value, (list, tuple)) or len(value) != 4
                    or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
                raise ConfigError(key, "must be four integers [x0, y0, x1, y1] in pixels", value, source)
            x0, y0, x1, y1 = value
            if not (0 <= x0 < x1 and 0 <= y0 < y1):
                raise ConfigError(key, "must satisfy 0 <= x0 < x1 and 0 <= y0 < y1", list(value), source)
            value = (x0, y0, x1, y1)
        if self.choices is not None and value not in self.choices:
            raise ConfigError(key, f"must be one of {', '.join(map(str, self.choices))}", value, source)
        if self.check is not None:
            problem = self.check(value)
            if problem:
                raise ConfigError(key, problem, value, source)
        return value


def section_values(keys: tuple[Key, ...], data: Any, section: str, source: str | None,
                   extra: tuple[str, ...] = (), origin: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Validate one mapping against ``keys``: unknown keys are errors, missing ones take defaults.

    ``origin`` maps a dotted key to where its value came from (an environment
    variable, an argument); errors name it instead of ``source``.
    """
    origin = origin or {}
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(section, "must be a mapping", data, origin.get(section, source))
    known = {k.name for k in keys}
    for name in data:
        if name not in known and name not in extra:
            raise ConfigError(f"{section}.{name}",
                              f"is not a known key (known: {', '.join(sorted(known | set(extra)))})",
                              data[name], origin.get(f"{section}.{name}", source))
    return {k.name: k.validate(section, data.get(k.name, k.default), origin.get(f"{section}.{k.name}", source))
            for k in keys}
