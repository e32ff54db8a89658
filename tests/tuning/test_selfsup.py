"""The reference-free selfsup loss: ranks good parameters above bad ones, never rewards an empty map."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import FrameError, ParameterWarning
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.tuning.metrics import mse
from uav_depth.tuning.selfsup import INVALID_COST, selfsup_loss, selfsup_terms

BAD = {
    "tiny-num-disparities": {"sgbm.num_disparities": 16},
    "huge-uniqueness-ratio": {"sgbm.uniqueness_ratio": 100},
    "overflowing-penalties": {"sgbm.p1": 40000, "sgbm.p2": 80000},
    "huge-block": {"sgbm.block_size": 31},
    "large-penalties": {"sgbm.p1": 8000, "sgbm.p2": 32000},
}


def _disparity(left, right, changes):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ParameterWarning)
        return DisparityPipeline(DEFAULT_PARAMS.replace(**changes)).compute(left, right)


@pytest.fixture(scope="module")
def baseline():
    """The motorcycle pair (BGR), its ground truth and the manual baseline's disparity, once per module."""
    from skimage import data

    left, right, gt = data.stereo_motorcycle()
    left, right = cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR)
    return left, right, gt.astype(np.float32), _disparity(left, right, {})


@pytest.mark.parametrize("name", sorted(BAD))
def test_manual_baseline_ranks_above_bad_parameters(baseline, name):
    left, right, gt, base = baseline
    bad = _disparity(left, right, BAD[name])
    assert mse(gt, bad) > mse(gt, base)          # the premise: these really are worse
    assert selfsup_loss(left, right, base) < selfsup_loss(left, right, bad)


def test_grey_input_ranks_the_same(baseline):
    left, right, _, _ = baseline
    gl, gr = (cv2.cvtColor(x, cv2.COLOR_BGR2GRAY) for x in (left, right))
    base = _disparity(gl, gr, {})
    for changes in BAD.values():
        assert selfsup_loss(gl, gr, base) < selfsup_loss(gl, gr, _disparity(gl, gr, changes))


def test_empty_map_scores_worst(baseline):
    left, right, _, base = baseline
    h, w = base.shape
    empty = np.full((h, w), np.nan, np.float32)
    assert selfsup_loss(left, right, empty) == INVALID_COST == 1.0
    rng = np.random.default_rng(0)
    for disp in (base, np.zeros((h, w), np.float32), rng.uniform(0, 64, (h, w)).astype(np.float32)):
        assert selfsup_loss(left, right, disp) < 1.0
    # Matches that fall outside the right image are no better than no answer.
    assert selfsup_loss(left, right, np.full((h, w), w + 5.0, np.float32)) == 1.0


def test_ground_truth_beats_perturbed_ground_truth(baseline):
    left, right, gt, _ = baseline
    truth = np.where(np.isfinite(gt), gt, np.nan).astype(np.float32)
    rng = np.random.default_rng(1)
    losses = [selfsup_loss(left, right, truth + rng.normal(0, s, truth.shape).astype(np.float32))
              for s in (0.0, 0.5, 2.0, 8.0)]
    assert losses == sorted(losses) and len(set(losses)) == 4
    for wrong in (truth + 3.0, truth * 0.9, truth * 1.1):
        assert selfsup_loss(left, right, truth) < selfsup_loss(left, right, wrong)


def test_exact_disparity_of_a_synthetic_pair_reconstructs_well(small_frame):
    _, frame = small_frame
    exact = selfsup_terms(frame.left, frame.right, frame.disparity)
    shifted = selfsup_terms(frame.left, frame.right, frame.disparity + 4.0)
    assert exact.photo < 0.5 * shifted.photo and exact.loss < shifted.loss
    assert exact.usable > 0.9


def test_terms_are_bounded(baseline):
    left, right, _, base = baseline
    t = selfsup_terms(left, right, base)
    assert 0 <= t.photo <= 1 and 0 <= t.smooth <= 1 and 0 < t.usable < 1 and 0 < t.loss < 1
    assert t.loss == pytest.approx(selfsup_loss(left, right, base))


@pytest.mark.parametrize("make,match", [
    (lambda l, r, d: (l, r, d[:-1]), "disparity must be"),
    (lambda l, r, d: (l, r[:, :-1], d), "same shape"),
    (lambda l, r, d: (l.astype(np.float32), r, d), "must be uint8"),
], ids=["disparity-shape", "pair-shape", "dtype"])
def test_bad_input_is_clear(baseline, make, match):
    left, right, _, base = baseline
    with pytest.raises(FrameError, match=match):
        selfsup_loss(*make(left, right, base))
