import warnings

import numpy as np
import pytest

from uav_depth.daemon.disparity import DisparityPipeline
from uav_depth.daemon.errors import FrameError, ParameterWarning
from uav_depth.daemon.params import DEFAULT_PARAMS


def test_output_contract(small_frame):
    _, f = small_frame
    res = DisparityPipeline(DEFAULT_PARAMS).run(f.left, f.right)
    assert res.disparity.shape == f.left.shape[:2] and res.disparity.dtype == np.float32
    assert np.isnan(res.disparity).any() and np.isfinite(res.disparity).mean() > 0.5
    assert res.confidence is not None and 0 <= res.confidence.min() and res.confidence.max() <= 1
    ok = np.isfinite(res.disparity) & f.branch_mask
    assert np.median(np.abs(res.disparity[ok] - f.disparity[ok])) < 1.0


def test_colour_and_grey_input(small_frame):
    _, f = small_frame
    colour = DisparityPipeline(DEFAULT_PARAMS).compute(np.dstack([f.left] * 3), np.dstack([f.right] * 3))
    assert colour.shape == f.left.shape


# Each of the paper's nine parameters alone, to a value that must change the output.
# Without re-setting what createDisparityWLSFilter clobbers, disp12_max_diff,
# uniqueness_ratio and speckle_window_size would be dead.
NINE = [("sgbm.p1", 50), ("sgbm.p2", 20000), ("sgbm.disp12_max_diff", 5), ("sgbm.pre_filter_cap", 20),
        ("sgbm.uniqueness_ratio", 40), ("sgbm.speckle_window_size", 1000), ("sgbm.speckle_range", 1),
        ("wls.lambda", 100.0), ("wls.sigma_color", 0.3)]


@pytest.mark.parametrize("key,value", NINE, ids=[k for k, _ in NINE])
def test_each_paper_parameter_is_live(motorcycle, key, value):
    left, right, _ = motorcycle
    base = DisparityPipeline(DEFAULT_PARAMS).compute(left, right)
    changed = DisparityPipeline(DEFAULT_PARAMS.replace(**{key: value})).compute(left, right)
    differ = ~((base == changed) | (np.isnan(base) & np.isnan(changed)))
    assert differ.mean() > 0.001, f"{key} has no effect"


def test_wls_filter_does_not_clobber_matcher():
    p = DisparityPipeline(DEFAULT_PARAMS.replace(**{"sgbm.disp12_max_diff": 3, "sgbm.uniqueness_ratio": 15,
                                                     "sgbm.speckle_window_size": 50}))
    m = p.left_matcher
    assert (m.getDisp12MaxDiff(), m.getUniquenessRatio(), m.getSpeckleWindowSize()) == (3, 15, 50)


def test_overflowing_penalties_give_all_nan_and_warning(motorcycle):
    left, right, _ = motorcycle
    params = DEFAULT_PARAMS.replace(**{"sgbm.p1": 100000, "sgbm.p2": 200000})
    with pytest.warns(ParameterWarning, match="16-bit cost limit"):
        res = DisparityPipeline(params).run(left, right)
    assert np.isnan(res.disparity).all() and res.warning


def test_largest_safe_penalties_still_compute(small_frame):
    _, f = small_frame
    with warnings.catch_warnings():
        warnings.simplefilter("error", ParameterWarning)
        d = DisparityPipeline(DEFAULT_PARAMS.replace(**{"sgbm.p1": 16000, "sgbm.p2": 32767})).compute(f.left, f.right)
    assert d.shape == f.left.shape


@pytest.mark.parametrize("left,right,msg", [
    (np.zeros((0, 0), np.uint8), np.zeros((0, 0), np.uint8), "empty"),
    (np.zeros((10, 20), np.uint8), np.zeros((10, 21), np.uint8), "same shape"),
    (np.zeros((10, 20), np.float32), np.zeros((10, 20), np.float32), "must be uint8"),
], ids=["empty", "mismatch", "dtype"])
def test_corrupt_frames_raise_frame_error(left, right, msg):
    with pytest.raises(FrameError, match=msg):
        DisparityPipeline(DEFAULT_PARAMS).compute(left, right)
