"""The ranging's quantiles: on the matcher's grid and off it, they equal the sorted definition."""

import numpy as np
import pytest

from uav_depth.core.ranging.stats import count_median, weighted_quantiles


def _sorted_quantiles(values, weights, *qs):
    """The definition: sort, accumulate the weight, take the first value where it reaches q."""
    order = np.argsort(values, kind="stable")
    v, cum = values[order], np.cumsum(weights[order], dtype=np.float64)
    return [float(v[min(int(np.searchsorted(cum, q * cum[-1])), v.size - 1)]) for q in qs]


@pytest.mark.parametrize("step", [1 / 16, 1 / 8, 1.0])
def test_weighted_quantiles_on_the_matchers_grid_equal_the_sorted_definition(step):
    # The histogram path (values on SGBM's 1/16 px grid) must give exactly what sorting gives, with
    # confidence-like float weights, zero weights and ties, at q = 0 and 1 too.
    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(1, 2000))
        values = (rng.integers(0, int(rng.integers(1, 700)), n) * step + 3.0).astype(np.float32)
        weights = rng.random(n).astype(np.float32)
        weights[rng.random(n) < 0.2] = 0.0
        qs = (0.0, 0.5, 0.9, 1.0, float(rng.random()))
        assert weighted_quantiles(values, weights, *qs) == _sorted_quantiles(values, weights, *qs)


@pytest.mark.parametrize("step", [1 / 16, None])
def test_unweighted_quantiles_count_what_unit_weights_sum(step):
    # weights None (the thin guard's pixels, each weighing 1) counts instead of summing: the same values as
    # ones, on the matcher's grid (the histogram) and off it (the sort).
    rng = np.random.default_rng(9)
    for _ in range(200):
        n = int(rng.integers(1, 1500))
        values = (rng.integers(0, 600, n) * step + 2.0 if step else rng.uniform(2.0, 60.0, n)).astype(np.float32)
        qs = (0.0, 0.2, 0.5, 1.0, float(rng.random()))
        assert weighted_quantiles(values, None, *qs) == _sorted_quantiles(values, np.ones(n), *qs)


def test_the_median_of_pixel_indices_from_their_histogram_is_numpys():
    rng = np.random.default_rng(10)
    for n in [1, 2, 3, 4, 5, 64, 65, 1024, 1025, 3000]:
        for hi in (1, 3, 720):
            idx = rng.integers(0, hi, n)
            assert count_median(np.bincount(idx, minlength=hi + 5)) == float(np.median(idx))


def test_weighted_quantiles_off_the_grid_fall_back_to_the_sort():
    rng = np.random.default_rng(8)
    values = rng.uniform(5.0, 60.0, 500)          # exact disparities: not on any 1/16 px grid
    weights = rng.random(500)
    assert weighted_quantiles(values, weights, 0.1, 0.5) == _sorted_quantiles(values, weights, 0.1, 0.5)
    assert weighted_quantiles(values, np.ones(500), 0.5)[0] in values
