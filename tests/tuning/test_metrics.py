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
