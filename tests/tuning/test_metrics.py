import math

import numpy as np
import pytest
from skimage.metrics import mean_squared_error, peak_signal_noise_ratio, structural_similarity

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.tuning import metrics


def test_hand_computed_small_case():
    ref = np.array([[10.0, 20.0], [np.nan, 0.0]])
    est = np.array([[11.0, np.nan], [5.0, 7.0]])
    # valid ref pixels: 10 and 20; est NaN counts as 0 -> errors 1 and 20
    assert metrics.mse(ref, est) == pytest.approx((1 + 400) / 2)
    assert metrics.psnr(ref, est) == pytest.approx(10 * math.log10(400 / 200.5))
    assert metrics.bad(ref, est, 1.0) == 50.0 and metrics.bad(ref, est, 0.5) == 100.0
    assert metrics.valid_fraction(ref, est) == 0.5


def test_matches_scikit_image_when_reference_is_full():
    rng = np.random.default_rng(0)
    ref = rng.uniform(1, 60, (40, 50))
    est = ref + rng.normal(0, 2, ref.shape)
    peak = ref.max()
    assert metrics.mse(ref, est) == pytest.approx(mean_squared_error(ref, est))
    assert metrics.psnr(ref, est) == pytest.approx(peak_signal_noise_ratio(ref, est, data_range=peak))
    assert metrics.ssim(ref, est) == pytest.approx(structural_similarity(ref, est, win_size=7, data_range=peak))


def test_an_empty_answer_never_scores_best():
    ref = np.full((20, 20), 30.0)
    good = ref + 1.0
    empty = np.full_like(ref, np.nan)
    assert metrics.mse(ref, good) < metrics.mse(ref, empty)
    assert metrics.ssim(ref, good) > metrics.ssim(ref, empty)


def test_perfect_estimate():
    ref = np.arange(1, 101, dtype=float).reshape(10, 10)
    s = metrics.score(ref, ref)
    assert s.mse == 0 and math.isinf(s.psnr) and s.ssim == pytest.approx(1.0) and s.bad2 == 0 and s.valid == 1


def test_motorcycle_baseline_is_sane(motorcycle):
    left, right, gt = motorcycle
    s = metrics.score(gt, DisparityPipeline(DEFAULT_PARAMS).compute(left, right))
    assert 50 < s.mse < 400 and 10 < s.psnr < 18 and 0.6 < s.ssim < 0.9 and s.bad2 < 35 and s.valid > 0.75


def test_fill_background_takes_the_smaller_neighbour_and_extends_the_ends():
    est = np.array([[np.nan, 5.0, np.nan, np.nan, 9.0, np.nan],
                    [np.nan, np.nan, np.nan, np.nan, np.nan, np.nan]])
    filled = metrics.fill_background(est)
    assert filled.tolist() == [[5.0, 5.0, 5.0, 5.0, 9.0, 9.0], [0.0] * 6]


def test_bench_answering_fewer_pixels_is_never_rewarded():
    ref = np.tile(np.linspace(10, 40, 60), (20, 1))
    good = ref.copy()
    sparse = good.copy()
    sparse[:, ::2] = np.nan                      # half the pixels unanswered, the other half as good
    wrong = good.copy()
    wrong[:, 30:] = 0.0                          # confidently wrong on the right half
    b_good = metrics.bench_scores(ref, good, 48.0, 0)
    b_sparse = metrics.bench_scores(ref, sparse, 48.0, 0)
    assert b_sparse["density"] == pytest.approx(0.5) and b_good["density"] == 1.0
    assert b_sparse["mae"] > b_good["mae"] == 0.0 and b_sparse["bad2"] >= b_good["bad2"]
    assert metrics.bench_scores(ref, wrong, 48.0, 0)["mae"] > b_sparse["mae"]


def test_bench_leaves_the_strip_out_and_uses_a_fixed_peak():
    ref = np.full((10, 40), 20.0)
    est = ref.copy()
    est[:, :8] = 0.0                             # wrong only inside the strip
    assert metrics.bench_scores(ref, est, 32.0, strip=8)["mae"] == 0.0
    assert metrics.bench_scores(ref, est, 32.0, strip=0)["mae"] == pytest.approx(20.0 * 8 / 40)
    noisy = ref + 1.0
    assert metrics.bench_scores(ref, noisy, 32.0)["psnr"] == pytest.approx(10 * math.log10(32.0 ** 2))
    assert metrics.strip_px(np.array([[0.0, 12.2], [3.0, np.nan]])) == 13
