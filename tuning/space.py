"""Search spaces: how a genome becomes validated :class:`StereoParams`.

Two spaces, one contract (:class:`Space`): ``sample(rng)`` draws a genome,
``decode(genome)`` returns the parameter *changes* (dotted schema keys) it
stands for, ``encode(params)`` goes back. Every range comes from
:data:`uav_depth.core.params.SPECS`; nothing here restates one. Candidates
are always built with ``base.replace(**changes)``, so the daemon's own schema
validates each one, and keys a space does not tune keep the base values (new
schema keys included).

- :class:`PaperSpace` is the faithful encoding of Lin et al. (2025): 29 integer
  genes 1..10, read as decimal digits.
- :class:`SchemaSpace` is the improved space: one unit-interval gene per
  schema key, with a scale that suits the key (log for penalties and lambda),
  bounds inside what OpenCV can compute, and the rules of the schema (odd,
  multiple of 16, p2 > p1) declared so every decoded candidate is valid.

Longer than 400 lines because the paper's 29-gene encoding and the schema-derived space share their bounds and constraints in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol, Sequence

import numpy as np

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import (OPENCV_COST_MAX, OPENCV_PRE_FILTER_CAP_FLOOR, SPEC_BY_KEY, SPECS, Spec,
                                     StereoParams)


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


def spec_for_symbol(symbol: str) -> Spec:
    """The schema key that carries one of the paper's symbols (alpha, beta, ..., sigma)."""
    for spec in SPECS:
        if spec.paper == symbol:
            return spec
    raise KeyError(f"no parameter-file key carries the paper's symbol {symbol!r}")


# -- faithful: the paper's 29 decimal genes -----------------------------------------------------------------------

#: Gene values are integers GENE_LO..GENE_HI (the paper's "1..10").
GENE_LO, GENE_HI = 1, 10

#: The paper's layout, in gene order: (symbol, number of genes, how the number is read).
#: "number": k genes read as the paper's alpha, giving 1..10**k.
#: "above:alpha": beta = alpha + number(x6..x10), so alpha < beta <= 200000 holds by construction.
#: "hundredths": sigma = ((x28-1)*10 + (x29-1)) / 100, 0..0.99 in steps of 0.01.
PAPER_LAYOUT: tuple[tuple[str, int, str], ...] = (
    ("alpha", 5, "number"),
    ("beta", 5, "above:alpha"),
    ("Delta", 2, "number"),
    ("eta", 2, "number"),
    ("gamma", 2, "number"),
    ("W", 3, "number"),
    ("delta", 3, "number"),
    ("lambda", 5, "number"),
    ("sigma", 2, "hundredths"),
)


def decode_number(genes: Sequence[int]) -> int:
    """The paper's reading of k genes: (x1-1)*10**(k-1) + ... + (x_{k-1}-1)*10 + x_k, in 1..10**k.

    It is a bijection: all digits but the last are x-1 (0..9), the last is x (1..10).
    """
    value = 0
    for g in genes[:-1]:
        value = value * 10 + (int(g) - 1)
    return value * 10 + int(genes[-1])


def encode_number(value: int, k: int) -> list[int]:
    """Inverse of :func:`decode_number` for 1 <= value <= 10**k."""
    if not 1 <= value <= 10 ** k:
        raise ValueError(f"{value} cannot be written with {k} of the paper's genes (1..{10 ** k})")
    last = (value - 1) % 10 + 1
    rest = (value - last) // 10
    digits = []
    for _ in range(k - 1):
        digits.append(rest % 10 + 1)
        rest //= 10
    return digits[::-1] + [last]


@dataclass(frozen=True)
class PaperSpace:
    """The paper's encoding: 29 integer genes in 1..10 (see :data:`PAPER_LAYOUT`).

    Which schema key each symbol sets is read from ``Spec.paper`` in the schema;
    the decoded value is validated by the schema when the candidate is built
    (sigma 0 from x28 = x29 = 1 is therefore a failed candidate, as the schema
    requires sigma > 0).
    """

    name: str = "paper"

    @property
    def size(self) -> int:
        return sum(k for _, k, _ in PAPER_LAYOUT)

    @property
    def low(self) -> list[int]:
        return [GENE_LO] * self.size

    @property
    def up(self) -> list[int]:
        return [GENE_HI] * self.size

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for symbol, k, _ in PAPER_LAYOUT:
            out[symbol] = slice(i, i + k)
            i += k
        return out

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return rng.integers(GENE_LO, GENE_HI + 1, size=self.size).astype(np.int64)

    def decode_symbols(self, genome: Sequence[float]) -> dict[str, float]:
        """The paper's symbols decoded from a genome (no schema check)."""
        g = [int(x) for x in genome]
        if len(g) != self.size or any(not GENE_LO <= x <= GENE_HI for x in g):
            raise ValueError(f"a paper genome has {self.size} genes in {GENE_LO}..{GENE_HI}, got {g}")
        out: dict[str, float] = {}
        i = 0
        for symbol, k, how in PAPER_LAYOUT:
            genes = g[i:i + k]
            i += k
            if how == "number":
                out[symbol] = decode_number(genes)
            elif how.startswith("above:"):
                out[symbol] = out[how.split(":")[1]] + decode_number(genes)
            elif how == "hundredths":
                out[symbol] = ((genes[0] - 1) * 10 + (genes[1] - 1)) / 100.0
            else:  # pragma: no cover - the layout above is the only input
                raise ValueError(how)
        return out

    def decode(self, genome: Sequence[float], base: StereoParams | None = None) -> dict[str, Any]:
        return {spec_for_symbol(sym).key: value for sym, value in self.decode_symbols(genome).items()}

    def encode(self, params: StereoParams) -> np.ndarray:
        """Genes of ``params`` when the paper's encoding can hold them exactly, else ValueError."""
        genes: list[int] = []
        sym = {s: params.get(spec_for_symbol(s).key) for s, _, _ in PAPER_LAYOUT}
        for symbol, k, how in PAPER_LAYOUT:
            if how == "number":
                genes += encode_number(int(sym[symbol]), k)
            elif how.startswith("above:"):
                genes += encode_number(int(sym[symbol]) - int(sym[how.split(":")[1]]), k)
            else:
                hundredths = round(float(sym[symbol]) * 100)
                if not 0 <= hundredths <= 99 or abs(hundredths / 100 - sym[symbol]) > 1e-9:
                    raise ValueError(f"sigma {sym[symbol]} is not one of the paper's 0..0.99")
                genes += [hundredths // 10 + 1, hundredths % 10 + 1]
        return np.asarray(genes, dtype=np.int64)

    def describe(self) -> list[dict[str, Any]]:
        out, i = [], 1
        for symbol, k, how in PAPER_LAYOUT:
            out.append({"symbol": symbol, "key": spec_for_symbol(symbol).key, "genes": f"x{i}..x{i + k - 1}",
                        "decoding": how, "paper_range": spec_for_symbol(symbol).paper_range})
            i += k
        return out


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

#: The largest P1/P2 a candidate may win with (study.fragile_reason) and so the largest the improved space
#: searches: half of OpenCV's 16-bit cost limit. SGBM sums penalties along its paths in 16-bit costs, which
#: wrap a little above this on some images (issue 12: p2 27500 fine on one image, 29666 broke others), so
#: searching above it only spends evaluations on candidates that cannot be chosen. The paper's space keeps
#: the paper's ranges (faithful mode); its candidates above this are refused by the same rule.
WINNABLE_COST_MAX = OPENCV_COST_MAX // 2

#: Significant digits a decoded float keeps.
FLOAT_DIGITS = 4

#: A positive float key whose schema floor is 0 is searched from hi * this (0.01 for sigma's 100):
#: a log scale needs a positive lower end.
POSITIVE_FLOOR_FRACTION = 1e-4


@dataclass(frozen=True)
class Dim:
    """One gene u in [0, 1] mapped to one schema key.

    ``kind``: "float", "int", "odd", "multiple_of_16", "choice", "bool".
    ``lo``/``hi``: inclusive search bounds (inside the schema's). ``above``: a key
    decoded earlier whose value + 1 is the lower bound instead of ``lo`` (p2 > p1).
    ``shift``: a log scale searches log(v + shift), so that 0 or -1 fit on it.
    """

    key: str
    kind: str
    scale: str = "linear"
    lo: float = 0.0
    hi: float = 1.0
    choices: tuple[Any, ...] = ()
    above: str | None = None
    shift: float = 0.0

    def _t(self, v: float) -> float:
        return math.log(v + self.shift) if self.scale == "log" else float(v)

    def _inv(self, t: float) -> float:
        return math.exp(t) - self.shift if self.scale == "log" else t

    def _grid(self, lo: float, hi: float) -> tuple[float, float, float]:
        """(first, last, step) of the values this kind allows between lo and hi."""
        if self.kind == "odd":
            first = lo if int(lo) % 2 == 1 else lo + 1
            last = hi if int(hi) % 2 == 1 else hi - 1
            return first, last, 2
        if self.kind == "multiple_of_16":
            return 16 * math.ceil(lo / 16), 16 * math.floor(hi / 16), 16
        return lo, hi, 1 if self.kind == "int" else 0

    def decode(self, u: float, lo: float | None = None) -> Any:
        u = min(max(float(u), 0.0), 1.0)
        if self.kind in ("choice", "bool"):
            opts = self.choices if self.kind == "choice" else (False, True)
            return opts[min(int(u * len(opts)), len(opts) - 1)]
        first, last, step = self._grid(self.lo if lo is None else lo, self.hi)
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

    def encode(self, value: Any, lo: float | None = None) -> float:
        if self.kind in ("choice", "bool"):
            opts = self.choices if self.kind == "choice" else (False, True)
            return (opts.index(value) + 0.5) / len(opts)
        first, last, step = self._grid(self.lo if lo is None else lo, self.hi)
        if (step == 2 or step == 16) and self.scale != "log":
            n = int((last - first) // step) + 1
            k = min(max(round((value - first) / step), 0), n - 1)
            return (k + 0.5) / n
        value = min(max(float(value), first), last)
        t0, t1 = self._t(first), self._t(last)
        return 0.5 if t1 == t0 else (self._t(value) - t0) / (t1 - t0)

    def describe(self) -> dict[str, Any]:
        d: dict[str, Any] = {"key": self.key, "kind": self.kind, "scale": self.scale}
        if self.kind in ("choice", "bool"):
            d["choices"] = list(self.choices) if self.kind == "choice" else [False, True]
        else:
            d["lo"] = f"{self.above} + 1" if self.above else self.lo
            d["hi"] = self.hi
        return d


def dim_for(key: str, scale: str | None = None) -> Dim:
    """The search dimension of one schema key, bounds from its Spec.

    Tightened only by facts about OpenCV: penalties stop at WINNABLE_COST_MAX
    (above it SGBM's 16-bit costs wrap on some images, and such a candidate may not
    win), p1 stops one below so p2 > p1 always has room, and preFilterCap starts at
    OpenCV's floor.
    """
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
    lo, hi = float(spec.lo), float(spec.hi)
    above = None
    if key == "sgbm.p1":
        hi = min(hi, WINNABLE_COST_MAX) - 1
    elif key == "sgbm.p2":
        hi = min(hi, WINNABLE_COST_MAX)
        above = "sgbm.p1"
    elif key == "sgbm.pre_filter_cap":
        lo = max(lo, OPENCV_PRE_FILTER_CAP_FLOOR)
    if spec.kind is float and spec.rule == "positive" and lo <= 0:
        lo = hi * POSITIVE_FLOOR_FRACTION
    # "0 (off) or a multiple of 16" (compute.fine_disparities) is the multiple-of-16 grid from 0
    rule = "multiple_of_16" if spec.rule == "zero_or_multiple_of_16" else spec.rule
    kind = rule if rule in ("odd", "multiple_of_16") else ("int" if spec.kind is int else "float")
    shift = 0.0
    if scale == "log" and lo <= 0:
        shift = 1.0 - lo  # log(v - lo + 1): 0 at the lower bound
    return Dim(key, kind, scale, lo, hi, above=above, shift=shift)


@dataclass(frozen=True)
class SchemaSpace:
    """The improved space: genome u in [0, 1]^n, one gene per key in ``keys``."""

    keys: tuple[str, ...] = DEFAULT_KEYS
    name: str = "schema"
    dims: tuple[Dim, ...] = field(init=False)

    def __post_init__(self) -> None:
        keys = tuple(dict.fromkeys(self.keys))
        if "sgbm.p2" in keys and "sgbm.p1" in keys and keys.index("sgbm.p2") < keys.index("sgbm.p1"):
            keys = tuple(k for k in keys if k != "sgbm.p2")
            keys = keys[:keys.index("sgbm.p1") + 1] + ("sgbm.p2",) + keys[keys.index("sgbm.p1") + 1:]
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
        out: dict[str, Any] = {}
        for dim, u in zip(self.dims, genome):
            lo = None
            if dim.above is not None:
                # p2 tuned without p1: above the base's p1 (the caller's base is validated)
                ref = out.get(dim.above, (base or StereoParams()).get(dim.above))
                lo = ref + 1
            out[dim.key] = dim.decode(u, lo)
        return out

    def encode(self, params: StereoParams) -> np.ndarray:
        out = []
        for dim in self.dims:
            lo = params.get(dim.above) + 1 if dim.above else None
            out.append(dim.encode(params.get(dim.key), lo))
        return np.asarray(out, dtype=np.float64)

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
