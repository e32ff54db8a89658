"""The fine pass: a box re-matched at full resolution over a shifted search, only in the flight pipeline."""

import numpy as np
import pytest

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS


# -- the fine pass ------------------------------------------------------------------------------------------------

HALF_FINE = DEFAULT_PARAMS.replace(**{"compute.scale": 0.5, "compute.grey": True, "sgbm.block_size": 3,
                                      "sgbm.p1": 72, "sgbm.p2": 288, "sgbm.num_disparities": 32,
                                      "compute.fine_disparities": 32})


def _branch_box(cfg, frame):
    x0, y0, x1, y1 = cfg.center_roi
    ys, xs = np.nonzero(frame.branch_mask[y0:y1, x0:x1])
    return x0 + int(xs.min()), y0 + int(ys.min()), x0 + int(xs.max()) + 1, y0 + int(ys.max()) + 1


def test_the_fine_pass_matches_a_box_at_full_resolution_over_a_shifted_search(small_frame):
    """Branch at 1 m (12.6 px): the box matched from d0 = 4 and from d0 = 0 reads the exact disparity on the
    branch (the shift is added back); from d0 = 14 the search starts above it and the branch is not found."""
    from uav_depth.core.disparity.fine import FineMatcher

    cfg, f = small_frame
    box = _branch_box(cfg, f)
    x0, y0, x1, y1 = box
    exact, branch = f.disparity[y0:y1, x0:x1], f.branch_mask[y0:y1, x0:x1]
    fine = FineMatcher(HALF_FINE)
    errs = {}
    for d0 in (0, 4, 14):
        fm = fine.match(f.left, f.right, box, d0)
        assert fm.box == box and fm.measured.shape == exact.shape and fm.confidence.shape == exact.shape
        assert (fm.d_lo, fm.d_hi) == (d0, d0 + 31)
        ok = branch & np.isfinite(fm.measured) & (fm.confidence >= 0.5)
        errs[d0] = (np.abs(fm.measured[ok] - exact[ok]), ok.sum() / branch.sum())
    for d0 in (0, 4):
        err, share = errs[d0]
        assert share > 0.5 and np.median(err) < 0.3
    err, _ = errs[14]
    assert (err < 0.5).sum() < 0.1 * branch.sum()


def test_the_fine_pass_confidence_over_its_box_is_the_whole_crop_s(small_frame, monkeypatch):
    """The fine pass computes the confidence on the box's columns only (the crop's margins are for the search):
    each value it keeps is the one the crop's whole map holds."""
    import uav_depth.core.disparity.fine as fine_module
    from uav_depth.core.disparity.confidence import lr_confidence

    seen = []

    def both(left16, right16, sgbm, resize_factor=1.0, cols=None):
        part = lr_confidence(left16, right16, sgbm, resize_factor, cols)
        whole = lr_confidence(left16, right16, sgbm, resize_factor)
        seen.append((cols, part, whole))
        return part

    monkeypatch.setattr(fine_module, "lr_confidence", both)
    cfg, f = small_frame
    box = _branch_box(cfg, f)
    fm = fine_module.FineMatcher(HALF_FINE).match(f.left, f.right, box, 4)
    (cols, part, whole), = seen
    c0, c1 = cols
    assert c1 - c0 == box[2] - box[0] and c1 < whole.shape[1]     # the box's columns, not the crop's
    assert (whole[:, c0:c1] > 0).mean() > 0.5
    assert np.array_equal(part[:, c0:c1], whole[:, c0:c1])
    assert fm.confidence.shape == (box[3] - box[1], box[2] - box[0])


def test_the_fine_pass_runs_only_in_the_flight_pipeline_below_full_resolution(small_frame):
    from uav_depth.core.disparity import flight_pipeline

    _, f = small_frame
    assert flight_pipeline(HALF_FINE).run(f.left, f.right).fine is not None
    assert flight_pipeline(HALF_FINE.replace(**{"compute.fine_disparities": 0})).run(f.left, f.right).fine is None
    assert flight_pipeline(HALF_FINE.replace(**{"compute.scale": 1.0})).run(f.left, f.right).fine is None
    assert DisparityPipeline(HALF_FINE).run(f.left, f.right).fine is None     # the tuner's faithful pipeline


def test_fine_disparities_is_off_or_a_multiple_of_16():
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.params import params_from_dict

    assert params_from_dict({"compute": {"fine_disparities": 0}}).compute.fine_disparities == 0
    assert params_from_dict({"compute": {"fine_disparities": 48}}).compute.fine_disparities == 48
    for bad in (20, -16, 272):
        with pytest.raises(ConfigError, match="compute.fine_disparities"):
            params_from_dict({"compute": {"fine_disparities": bad}})


def test_the_fine_pass_near_the_image_edge_leaves_what_it_cannot_match_unmeasured(small_frame):
    """A box starting left of d0 (its partners would lie outside the right image) keeps the box's shape:
    the columns the shifted search cannot reach are NaN, not shifted data."""
    from uav_depth.core.disparity.fine import FineMatcher

    _, f = small_frame
    fine = FineMatcher(HALF_FINE)
    fm = fine.match(f.left, f.right, (10, 100, 120, 140), 40)
    assert fm.measured.shape == fm.confidence.shape == (40, 110)
    assert np.isnan(fm.measured[:, :30]).all() and (fm.confidence[:, :30] == 0).all()   # x < d0 = 40
    assert fine.match(f.left, f.right, (10, 100, 60, 140), 40) is None                  # nothing left to match
