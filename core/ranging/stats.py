"""Quantiles of the matcher's disparities (weighted, on SGBM's 1/16 px grid by a histogram, else by a sort), the median
of pixel indices from their histogram, and the share of a bool map."""

from __future__ import annotations

import numpy as np

#: SGBM's disparity grid (levels per px) and the most levels :func:`weighted_quantiles` sums a histogram over.
_QUANTILE_GRID = 16.0
_QUANTILE_MAX_LEVELS = 1 << 16


def weighted_quantiles(values: np.ndarray, weights: np.ndarray | None, *qs: float) -> list[float]:
    """The values that leave a share q of the weight below them, for each q (one histogram or one sort);
    ``weights`` None: each value weighs 1 (the same answer as ones, counted instead of summed).

    Tied values may be ordered either way: the value where the cumulative weight crosses
    q is the same, so the sort need not be stable (it is about twice as fast).

    Disparities from the matcher usually lie on SGBM's grid of 1/16 px (the coarse pass's at half
    scale on 1/8 input px, when the crop is a whole number of matched px): then the weight is summed
    per grid level instead (a histogram, no sort, a quarter of the ranging stage's time saved,
    docs/performance.md), and the answer is the first level whose cumulative weight reaches
    q, the same value the sort finds. Off the grid (a crop scaled by a fraction, exact disparities)
    the sort is used."""
    if values.size:
        v64 = values.astype(np.float64, copy=False)
        lo = float(v64.min())
        keys = np.rint((v64 - lo) * _QUANTILE_GRID)
        if keys.max() < _QUANTILE_MAX_LEVELS and np.array_equal(keys / _QUANTILE_GRID + lo, v64):
            cum = np.cumsum(np.bincount(keys.astype(np.intp), weights=weights))
            return [lo + float(min(int(np.searchsorted(cum, q * cum[-1])), cum.size - 1)) / _QUANTILE_GRID
                    for q in qs]
    order = np.argsort(values)
    v = values[order]
    cum = np.arange(1, v.size + 1) if weights is None else np.cumsum(weights[order], dtype=np.float64)
    return [float(v[min(int(np.searchsorted(cum, q * cum[-1])), v.size - 1)]) for q in qs]


def share_of(mask: np.ndarray) -> float:
    """``mask.mean()`` of a bool map (the share of it that is True, NaN when empty), by a count: ``mean``
    converts every pixel to float first and takes about ten times as long on a region's map."""
    return np.count_nonzero(mask) / mask.size if mask.size else float("nan")


def count_median(counts: np.ndarray) -> float:
    """The median of pixel indices given as a histogram (``counts[i]`` pixels at index i, at least one in all):
    ``np.median`` of the indices themselves, the same value, without listing them (the histogram is one
    reduction of a mask along an axis; ``np.nonzero`` and a sort of it cost about twice as much)."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    upper = float(np.searchsorted(cum, n // 2, side="right"))
    return upper if n % 2 else (float(np.searchsorted(cum, n // 2 - 1, side="right")) + upper) / 2.0


def weighted_median(values: np.ndarray, weights: np.ndarray | None) -> float:
    return weighted_quantiles(values, weights, 0.5)[0]
