"""The search space of Lin et al. (2025): 29 integer genes 1..10, read as decimal digits.

The genes are read exactly as the paper reads them (:meth:`PaperSpace.decode_symbols`: alpha, beta, ...,
sigma over the paper's ranges). The values a candidate gets are then placed inside what the daemon can fly
(:func:`~uav_depth.tuning.space.search_range`: the schema's bounds, OpenCV's limits and the rules between
keys, declared in core.params), so no proposal is spent on a candidate the schema could have refused
(docs/tuning.md, *Faithful mode*, rows 2, 4 and 6):

- P1 and P2 (alpha, beta) are *scaled*: the paper's alpha in 1..100000 is read as a fraction of its range and
  placed on the same fraction of 1..P1's largest winnable value; beta's five genes (beta - alpha in the paper)
  place P2 between P1 + 1 and its largest winnable value. The paper's ranges are 3 to 6 times OpenCV's 16-bit
  cost limit, where SGBM returns nothing, so most paper genomes would otherwise be failed trials.
- every other symbol is *clipped*: its paper value when the daemon accepts it, else the nearest value it does
  accept (uniqueness 100 with the 3-way mode becomes 99; sigma 0 becomes 0.01, the decoding's step).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from uav_depth.core.params import SPECS, Spec, StereoParams

from uav_depth.tuning.space import flat, search_range

#: Gene values are integers GENE_LO..GENE_HI (the paper's "1..10").
GENE_LO, GENE_HI = 1, 10

#: The paper's layout, in gene order: (symbol, number of genes, how the number is read, how it is placed).
#: "number": k genes read as the paper's alpha, giving 1..10**k.
#: "above:alpha": beta = alpha + number(x6..x10), so alpha < beta <= 200000 holds by construction.
#: "hundredths": sigma = ((x28-1)*10 + (x29-1)) / 100, 0..0.99 in steps of 0.01.
#: "scale": the number's place in 1..10**k becomes the same place in the accepted range (module docstring);
#: "clip": the paper's value, moved to the nearest accepted one when outside.
PAPER_LAYOUT: tuple[tuple[str, int, str, str], ...] = (
    ("alpha", 5, "number", "scale"),
    ("beta", 5, "above:alpha", "scale"),
    ("Delta", 2, "number", "clip"),
    ("eta", 2, "number", "clip"),
    ("gamma", 2, "number", "clip"),
    ("W", 3, "number", "clip"),
    ("delta", 3, "number", "clip"),
    ("lambda", 5, "number", "clip"),
    ("sigma", 2, "hundredths", "clip"),
)
#: The smallest step of each reading: a positive key's exclusive floor 0 is clipped up to it.
STEP = {"number": 1, "above:alpha": 1, "hundredths": 0.01}


def spec_for_symbol(symbol: str) -> Spec:
    """The schema key that carries one of the paper's symbols (alpha, beta, ..., sigma)."""
    for spec in SPECS:
        if spec.paper == symbol:
            return spec
    raise KeyError(f"no parameter-file key carries the paper's symbol {symbol!r}")


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


def _scaled(n: int, k: int, lo: float, hi: float) -> int:
    """The value at the place of ``n`` in 1..10**k, on lo..hi."""
    return int(lo + round((n - 1) * (hi - lo) / (10 ** k - 1)))


def _unscaled(value: int, k: int, lo: float, hi: float) -> int:
    """An ``n`` whose :func:`_scaled` is ``value`` (every value of lo..hi has one: 10**k is the larger range)."""
    guess = 1 if hi == lo else 1 + round((value - lo) * (10 ** k - 1) / (hi - lo))
    for n in (guess, guess - 1, guess + 1, guess - 2, guess + 2):
        if 1 <= n <= 10 ** k and _scaled(n, k, lo, hi) == value:
            return n
    raise ValueError(f"{value} is outside {lo:g}..{hi:g}, where the paper's genes are placed")


@dataclass(frozen=True)
class PaperSpace:
    """The paper's encoding: 29 integer genes in 1..10 (see :data:`PAPER_LAYOUT`).

    Which schema key each symbol sets is read from ``Spec.paper`` in the schema; where each value lands is
    read from :func:`~uav_depth.tuning.space.search_range` given the base and the keys decoded before it.
    """

    name: str = "paper"

    @property
    def size(self) -> int:
        return sum(k for _, k, _, _ in PAPER_LAYOUT)

    @property
    def low(self) -> list[int]:
        return [GENE_LO] * self.size

    @property
    def up(self) -> list[int]:
        return [GENE_HI] * self.size

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for symbol, k, _, _ in PAPER_LAYOUT:
            out[symbol] = slice(i, i + k)
            i += k
        return out

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return rng.integers(GENE_LO, GENE_HI + 1, size=self.size).astype(np.int64)

    def _numbers(self, genome: Sequence[float]) -> dict[str, int]:
        """Each symbol's number as its genes spell it (a hundredths pair: 0..99)."""
        g = [int(x) for x in genome]
        if len(g) != self.size or any(not GENE_LO <= x <= GENE_HI for x in g):
            raise ValueError(f"a paper genome has {self.size} genes in {GENE_LO}..{GENE_HI}, got {g}")
        out = {}
        for symbol, sl in self.slices().items():
            genes = g[sl]
            how = next(h for s, _, h, _ in PAPER_LAYOUT if s == symbol)
            out[symbol] = (genes[0] - 1) * 10 + (genes[1] - 1) if how == "hundredths" else decode_number(genes)
        return out

    def decode_symbols(self, genome: Sequence[float]) -> dict[str, float]:
        """The paper's symbols over the paper's ranges, as the paper reads them (no schema, no OpenCV)."""
        numbers, out = self._numbers(genome), {}
        for symbol, _, how, _ in PAPER_LAYOUT:
            if how.startswith("above:"):
                out[symbol] = out[how.split(":")[1]] + numbers[symbol]
            else:
                out[symbol] = numbers[symbol] / 100.0 if how == "hundredths" else numbers[symbol]
        return out

    def decode(self, genome: Sequence[float], base: StereoParams | None = None) -> dict[str, Any]:
        """The changes a genome stands for, every value one the daemon accepts given ``base``."""
        numbers, values, out = self._numbers(genome), flat(base or StereoParams()), {}
        for symbol, k, how, fit in PAPER_LAYOUT:
            spec = spec_for_symbol(symbol)
            lo, hi = self._range(spec, how, values)
            if fit == "scale":
                value: Any = _scaled(numbers[symbol], k, lo, hi)
            else:
                paper = numbers[symbol] / 100.0 if how == "hundredths" else numbers[symbol]
                value = spec.kind(min(max(paper, lo), hi))
            out[spec.key] = values[spec.key] = value
        return out

    @staticmethod
    def _range(spec: Spec, how: str, values: dict[str, Any]) -> tuple[float, float]:
        lo, hi = search_range(spec.key, values)
        if spec.rule == "positive" and lo <= 0:
            lo = STEP[how]
        return lo, max(lo, hi)

    def encode(self, params: StereoParams) -> np.ndarray:
        """Genes that decode to ``params``' values of the nine keys, else ValueError (a value the decoding
        cannot give: between the paper's steps, or outside where the genes are placed)."""
        genes: list[int] = []
        values = flat(params)
        for symbol, k, how, fit in PAPER_LAYOUT:
            spec = spec_for_symbol(symbol)
            value = values[spec.key]
            lo, hi = self._range(spec, how, values)
            if fit == "scale":
                genes += encode_number(_unscaled(int(value), k, lo, hi), k)
            elif how == "hundredths":
                hundredths = round(float(value) * 100)
                if not 0 <= hundredths <= 99 or abs(hundredths / 100 - value) > 1e-9:
                    raise ValueError(f"sigma {value} is not one of the paper's 0..0.99")
                genes += [hundredths // 10 + 1, hundredths % 10 + 1]
            else:
                genes += encode_number(int(value), k)
        return np.asarray(genes, dtype=np.int64)

    def describe(self) -> list[dict[str, Any]]:
        out, i = [], 1
        for symbol, k, how, fit in PAPER_LAYOUT:
            spec = spec_for_symbol(symbol)
            out.append({"symbol": symbol, "key": spec.key, "genes": f"x{i}..x{i + k - 1}", "decoding": how,
                        "paper_range": spec.paper_range, "placed": fit})
            i += k
        return out
