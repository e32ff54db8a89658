"""Search spaces: how a genome becomes validated :class:`StereoParams`.

Two spaces, one contract (:class:`Space`): ``sample(rng)`` draws a genome,
``decode(genome, base)`` returns the parameter *changes* (dotted schema keys) it
stands for, ``encode(params)`` goes back. Every range comes from the schema
(:data:`uav_depth.core.params.SPECS` and :func:`~uav_depth.core.params.accepted_range`, which holds the rules
between keys and OpenCV's limits); nothing here restates one. Candidates are always built with
``base.replace(**changes)``, so the daemon's own schema validates each one, and keys a space does not tune
keep the base values (new schema keys included).

- :class:`~uav_depth.tuning.paper_space.PaperSpace` is the encoding of Lin et al. (2025): 29 integer
  genes 1..10, read as decimal digits, decoded into what OpenCV accepts.
- :class:`SchemaSpace` (here) is the improved space: one unit-interval gene per
  schema key, with a scale that suits the key (log for penalties and lambda),
  bounds inside what OpenCV can compute, and the rules of the schema (odd,
  multiple of 16, the rules between keys) declared so every decoded candidate is valid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol, Sequence

import numpy as np

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import (ABOVE, CAPPED_WHEN, SUM_AT_LEAST, OPENCV_COST_MAX, OPENCV_PRE_FILTER_CAP_FLOOR, SPEC_BY_KEY,
                                     SPECS, StereoParams, accepted_range)


class Space(Protocol):
    """What an optimiser needs from a search space."""

    name: str

    @property
    def size(self) -> int: ...

    def sample(self, rng: np.random.Generator) -> np.ndarray: ...

    def decode(self, genome: Sequence[float], base: StereoParams | None = None) -> dict[str, Any]: ...

    def encode(self, params: StereoParams) -> np.ndarray: ...

    def describe(self) -> list[dict[str, Any]]: ...


def build(space: Space, genome: Sequence[float], base: StereoParams) -> StereoParams:
    """The candidate a genome stands for; raises ConfigError if the schema rejects it."""
    return base.replace(**space.decode(genome, base))


# -- improved: one unit gene per schema key -----------------------------------------------------------------------

#: How each key is best searched. Only *scales* live here; bounds come from SPECS.
#: "log": equal effort per decade (penalties, lambda, window sizes span orders of magnitude).
SCALES: dict[str, str] = {
    "sgbm.p1": "log",
    "sgbm.p2": "log",
    "sgbm.disp12_max_diff": "log",
    "sgbm.pre_filter_cap": "log",
    "sgbm.uniqueness_ratio": "log",
    "sgbm.speckle_window_size": "log",
    "sgbm.speckle_range": "log",
    "wls.lambda": "log",
    "wls.sigma_color": "log",
    "sgbm.num_disparities": "log",
}

#: Keys the improved space tunes by default: the paper's nine, plus the block size.
#: Not the mode: it is chosen for speed (the flight file's sgbm_3way) as much as for accuracy,
#: and the measured comparisons in the README were made without it; ``--keys`` adds it.
DEFAULT_KEYS: tuple[str, ...] = tuple(s.key for s in SPECS if s.paper) + ("sgbm.block_size",)

#: Keys whose value never reaches the flown result: the daemon ranges on the matcher's measured pixels and
#: their left-right confidence, which OpenCV computes before, and independently of, the WLS smoothing
#: (measured: distance, sigma, quality and confidence bit-identical for lambda 100..90000, sigma 0.3..5).
NOT_FLOWN_KEYS: tuple[str, ...] = ("wls.lambda", "wls.sigma_color")

#: Keys the flown fitnesses tune by default: the default keys that change what flies.
FLOWN_KEYS: tuple[str, ...] = tuple(k for k in DEFAULT_KEYS if k not in NOT_FLOWN_KEYS)

#: Speed levers of the schema that trade accuracy for frame time; added to the default keys
#: when the search has a frame-time budget (``--max-ms``), so the Pareto front has fast options.
SPEED_KEYS: tuple[str, ...] = tuple(k for k in ("compute.scale", "compute.grey") if k in SPEC_BY_KEY)

#: The largest P1/P2 a candidate may win with (choice.fragile_reason) and so the largest either space
#: decodes: half of OpenCV's 16-bit cost limit. SGBM sums penalties along its paths in 16-bit costs, which
#: wrap a little above this on some images (p2 27500 was fine on one real pair, 29666 broke others), so
#: searching above it only spends evaluations on candidates that cannot be chosen.
WINNABLE_COST_MAX = OPENCV_COST_MAX // 2
#: The tuner's caps on top of what the schema accepts (core.params.accepted_range's ``limits``).
SEARCH_LIMITS: dict[str, float] = {"sgbm.p1": WINNABLE_COST_MAX, "sgbm.p2": WINNABLE_COST_MAX}
#: The tuner's floors above what the schema accepts. Block size 1 (a one-pixel match, no block) is where the
#: flown fitness climbs and nothing can be chosen: in bench/new_rig.py's tunes on its three rigs
#: (docs/measurements/tuning-search-guide.md) the search guide passed 5 of the 742 block-1 candidates it read
#: (0.7 %) and 234 of the 569 at block 3 (41 %); every file tune wrote there has block 3; on the real pairs at
#: the default 30 x 100 every block-1 candidate failed the block-size nudge (robust.nudge_check). Searched,
#: block 1 took half of what the search read on the guide. A file may still hold it (the schema's floor).
SEARCH_FLOORS: dict[str, float] = {"sgbm.block_size": 3}


def search_range(key: str, values: Mapping[str, Any]) -> tuple[float, float]:
    """Where a space may put ``key`` given the other keys' ``values`` (the base's, overridden by what the
    genome decoded before it): what a flown file may hold, capped by :data:`SEARCH_LIMITS`."""
    return accepted_range(key, values, SEARCH_LIMITS)


def depends_on(key: str) -> tuple[str, ...]:
    """The keys whose value narrows ``key``'s range (core.params.ABOVE, CAPPED_WHEN): decoded before it."""
    return tuple(o for rules in (ABOVE, SUM_AT_LEAST, CAPPED_WHEN) for k, o, *_ in rules if k == key)


def flat(params: StereoParams) -> dict[str, Any]:
    """Every key of ``params`` by its dotted name."""
    return {s.key: params.get(s.key) for s in SPECS}

#: Significant digits a decoded float keeps.
FLOAT_DIGITS = 4

#: A positive float key whose schema floor is 0 is searched from hi * this (0.01 for sigma's 100):
#: a log scale needs a positive lower end.
POSITIVE_FLOOR_FRACTION = 1e-4


@dataclass(frozen=True)
class Dim:
    """One gene u in [0, 1] mapped to one schema key.

    ``kind``: "float", "int", "odd", "multiple_of_16", "choice", "bool".
    ``lo``/``hi``: inclusive search bounds (inside the schema's). ``narrowed_by``: keys whose value narrows
    this one's range (core.params' rules between keys: p2 above p1, uniqueness capped with the 3-way mode);
    the space decodes them first and passes the narrowed bounds to :meth:`decode`.
    ``shift``: a log scale searches log(v + shift), so that 0 or -1 fit on it.
    """

    key: str
    kind: str
    scale: str = "linear"
    lo: float = 0.0
    hi: float = 1.0
    choices: tuple[Any, ...] = ()
    narrowed_by: tuple[str, ...] = ()
    shift: float = 0.0

    def _t(self, v: float) -> float:
        return math.log(v + self.shift) if self.scale == "log" else float(v)

    def _inv(self, t: float) -> float:
        return math.exp(t) - self.shift if self.scale == "log" else t

    def _grid(self, lo: float | None, hi: float | None) -> tuple[float, float, float]:
        """(first, last, step) of the values this kind allows between lo and hi (default: the dim's)."""
        lo = self.lo if lo is None else lo
        hi = self.hi if hi is None else hi
        if self.kind == "odd":
            first = lo if int(lo) % 2 == 1 else lo + 1
            last = hi if int(hi) % 2 == 1 else hi - 1
            return first, last, 2
        if self.kind == "multiple_of_16":
            return 16 * math.ceil(lo / 16), 16 * math.floor(hi / 16), 16
        return lo, hi, 1 if self.kind == "int" else 0

    def decode(self, u: float, lo: float | None = None, hi: float | None = None) -> Any:
        u = min(max(float(u), 0.0), 1.0)
        if self.kind in ("choice", "bool"):
            opts = self.choices if self.kind == "choice" else (False, True)
            return opts[min(int(u * len(opts)), len(opts) - 1)]
        first, last, step = self._grid(lo, hi)
        if (step == 2 or step == 16) and self.scale != "log":
            # uniform over the allowed values: pick by index
            n = int((last - first) // step) + 1
            return int(first + step * min(int(u * n), n - 1))
        t0, t1 = self._t(first), self._t(last)
        v = self._inv(t0 + u * (t1 - t0))
        if step == 2 or step == 16:  # log scale over a grid: the nearest allowed value
            return int(min(max(first + step * round((v - first) / step), first), last))
        if self.kind == "int":
            return int(min(max(round(v), first), last))
        # FLOAT_DIGITS significant digits: the baseline's 8000 and 1.5 come back exactly,
        # the parameter file stays readable, and near-equal floats share one cache entry.
        return float(min(max(float(f"{v:.{FLOAT_DIGITS}g}"), first), last))

    def encode(self, value: Any, lo: float | None = None, hi: float | None = None) -> float:
        if self.kind in ("choice", "bool"):
            opts = self.choices if self.kind == "choice" else (False, True)
            return (opts.index(value) + 0.5) / len(opts)
        first, last, step = self._grid(lo, hi)
        if (step == 2 or step == 16) and self.scale != "log":
            n = int((last - first) // step) + 1
            k = min(max(round((value - first) / step), 0), n - 1)
            return (k + 0.5) / n
        value = min(max(float(value), first), last)
        t0, t1 = self._t(first), self._t(last)
        return 0.5 if t1 == t0 else (self._t(value) - t0) / (t1 - t0)

    def narrowed(self, values: Mapping[str, Any]) -> tuple[float | None, float | None]:
        """(lo, hi) of this key given the other keys' ``values`` (None, None when nothing narrows it)."""
        if not self.narrowed_by:
            return None, None
        lo, hi = search_range(self.key, values)
        lo, hi = max(self.lo, lo), min(self.hi, hi)
        return lo, max(lo, hi)      # a base above the search's cap leaves one value: the schema's floor

    def describe(self) -> dict[str, Any]:
        d: dict[str, Any] = {"key": self.key, "kind": self.kind, "scale": self.scale}
        if self.kind in ("choice", "bool"):
            d["choices"] = list(self.choices) if self.kind == "choice" else [False, True]
        else:
            d["lo"], d["hi"] = self.lo, self.hi
            if self.narrowed_by:
                d["narrowed_by"] = list(self.narrowed_by)
        return d


def dim_for(key: str, scale: str | None = None) -> Dim:
    """The search dimension of one schema key: its range from :func:`search_range` (the schema's bounds,
    OpenCV's limits, the tuner's cap on P1/P2), the tuner's :data:`SEARCH_FLOORS`, and preFilterCap from
    OpenCV's floor (below it every value gives the same map)."""
    if key not in SPEC_BY_KEY:
        raise ConfigError("--keys", f"must name parameter-file keys (known: {', '.join(SPEC_BY_KEY)})", key)
    spec = SPEC_BY_KEY[key]
    scale = scale or SCALES.get(key, "linear")
    if spec.kind is bool:
        return Dim(key, "bool")
    if spec.choices is not None:
        return Dim(key, "choice", choices=tuple(spec.choices))
    if spec.kind not in (int, float) or spec.lo is None or spec.hi is None:
        raise ConfigError("--keys", "must name a numeric, choice or boolean key to tune", key)
    lo, hi = search_range(key, {})
    lo = max(lo, SEARCH_FLOORS.get(key, lo))
    if key == "sgbm.pre_filter_cap":
        lo = max(lo, OPENCV_PRE_FILTER_CAP_FLOOR)
    if spec.kind is float and spec.rule == "positive" and lo <= 0:
        lo = hi * POSITIVE_FLOOR_FRACTION
    # "0 (off) or a multiple of 16" (compute.fine_disparities) is the multiple-of-16 grid from 0
    rule = "multiple_of_16" if spec.rule == "zero_or_multiple_of_16" else spec.rule
    kind = rule if rule in ("odd", "multiple_of_16") else ("int" if spec.kind is int else "float")
    shift = 0.0
    if scale == "log" and lo <= 0:
        shift = 1.0 - lo  # log(v - lo + 1): 0 at the lower bound
    return Dim(key, kind, scale, lo, hi, narrowed_by=depends_on(key), shift=shift)


def decode_order(keys: Sequence[str]) -> tuple[str, ...]:
    """``keys`` (each once) with every key after the tuned keys that narrow it (:func:`depends_on`)."""
    out: list[str] = []
    for key in dict.fromkeys(keys):
        for dep in depends_on(key):
            if dep in keys and dep not in out:
                out.append(dep)
        if key not in out:
            out.append(key)
    return tuple(out)


@dataclass(frozen=True)
class SchemaSpace:
    """The improved space: genome u in [0, 1]^n, one gene per key in ``keys``."""

    keys: tuple[str, ...] = DEFAULT_KEYS
    name: str = "schema"
    dims: tuple[Dim, ...] = field(init=False)

    def __post_init__(self) -> None:
        keys = decode_order(self.keys)
        object.__setattr__(self, "keys", keys)
        object.__setattr__(self, "dims", tuple(dim_for(k) for k in keys))

    @property
    def size(self) -> int:
        return len(self.dims)

    @property
    def low(self) -> list[float]:
        return [0.0] * self.size

    @property
    def up(self) -> list[float]:
        return [1.0] * self.size

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return rng.random(self.size)

    def decode(self, genome: Sequence[float], base: StereoParams | None = None) -> dict[str, Any]:
        if len(genome) != self.size:
            raise ValueError(f"a {self.name} genome has {self.size} genes, got {len(genome)}")
        values = flat(base or StereoParams())     # keys not tuned narrow the others at the base's value
        out: dict[str, Any] = {}
        for dim, u in zip(self.dims, genome):
            out[dim.key] = values[dim.key] = dim.decode(u, *dim.narrowed(values))
        return out

    def encode(self, params: StereoParams) -> np.ndarray:
        values = flat(params)
        return np.asarray([dim.encode(values[dim.key], *dim.narrowed(values)) for dim in self.dims],
                          dtype=np.float64)

    def describe(self) -> list[dict[str, Any]]:
        return [d.describe() for d in self.dims]


def parse_keys(text: str | None, speed: bool = False, flown: bool = False) -> tuple[str, ...]:
    """``--keys``: comma-separated schema keys; "default" (or None) stands for DEFAULT_KEYS (FLOWN_KEYS
    when ``flown``: the fitness scores what flies), "paper" for the paper's nine, "speed" for SPEED_KEYS.
    ``speed``: None means the default + SPEED_KEYS. A flown fitness refuses keys that cannot change it."""
    default = FLOWN_KEYS if flown else DEFAULT_KEYS
    if not text:
        return default + SPEED_KEYS if speed else default
    keys: list[str] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        if part == "default":
            keys += default
        elif part == "paper":
            keys += [s.key for s in SPECS if s.paper]
        elif part == "speed":
            keys += SPEED_KEYS
        else:
            keys.append(part)
    for k in keys:
        dim_for(k)  # raises a ConfigError naming the bad key
        if flown and k in NOT_FLOWN_KEYS:
            raise ConfigError("--keys", "must change what flies: the flown fitness never sees the WLS smoothing, "
                              f"so {', '.join(NOT_FLOWN_KEYS)} cannot be tuned by it", k)
    return tuple(dict.fromkeys(keys))


def describe_space(space: Space) -> Mapping[str, Any]:
    return {"name": space.name, "genes": space.size, "dims": space.describe()}
