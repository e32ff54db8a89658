"""The disparity pipeline's contract: the paper's parameters live, OpenCV's sample pipeline, the speed levers."""

import warnings

import numpy as np
import pytest

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import FrameError, ParameterWarning
from uav_depth.core.params import DEFAULT_PARAMS

from disparity_cases import ROI


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
    m = p.match.matchers.left
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


# -- the speed levers (compute.*) -------------------------------------------------------------------------------


def test_defaults_are_opencv_sample_pipeline_bit_for_bit(small_frame):
    """The manual baseline stays what OpenCV's sample computes: full frame, full resolution, as given."""
    import cv2

    _, f = small_frame
    left, right = np.dstack([f.left] * 3), np.dstack([f.right] * 3)
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5, P1=600, P2=2400, disp12MaxDiff=1,
                              preFilterCap=63, uniquenessRatio=10, speckleWindowSize=100, speckleRange=32)
    wls = cv2.ximgproc.createDisparityWLSFilter(m)
    m.setDisp12MaxDiff(1), m.setUniquenessRatio(10), m.setSpeckleWindowSize(100)
    wls.setLambda(8000.0), wls.setSigmaColor(1.5)
    rm = cv2.ximgproc.createRightMatcher(m)
    l16 = m.compute(left, right)
    want = wls.filter(l16, left, disparity_map_right=rm.compute(right, left)).astype(np.float32) / 16
    want[want < 0] = np.nan
    res = DisparityPipeline(DEFAULT_PARAMS).run(left, right)
    assert np.array_equal(res.disparity, want, equal_nan=True)


def test_grey_lever_is_converting_first(small_frame):
    """compute.grey on colour input gives exactly the baseline on the converted grey pair."""
    import cv2

    _, f = small_frame
    tint = np.array([0.8, 1.0, 1.1])
    left = np.clip(f.left[..., None] * tint, 0, 255).astype(np.uint8)
    right = np.clip(f.right[..., None] * tint, 0, 255).astype(np.uint8)
    grey = DisparityPipeline(DEFAULT_PARAMS.replace(**{"compute.grey": True})).run(left, right)
    conv = DisparityPipeline(DEFAULT_PARAMS).run(cv2.cvtColor(left, cv2.COLOR_BGR2GRAY),
                                                 cv2.cvtColor(right, cv2.COLOR_BGR2GRAY))
    for name in ("disparity", "measured", "confidence"):
        assert np.array_equal(getattr(grey, name), getattr(conv, name), equal_nan=True), name


@pytest.mark.parametrize("changes", [
    {"compute.roi": ROI},
    {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64},
    {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64, "sgbm.mode": "sgbm_3way",
     "compute.grey": True},
    {"compute.scale": 0.5, "sgbm.num_disparities": 64},
    {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64, "compute.wls_at": "matched"},
], ids=["roi", "roi-half", "roi-half-3way-grey", "half-full-frame", "roi-half-wls-matched"])
def test_levers_keep_the_contract_and_the_branch_disparity(small_frame, changes):
    """Full-size maps in input pixels whatever the levers; NaN (confidence 0) outside the region;
    the branch's disparity within a pixel of the truth."""
    cfg, f = small_frame
    params = DEFAULT_PARAMS.replace(**changes)
    res = DisparityPipeline(params).run(f.left, f.right)
    h, w = f.left.shape
    x0, y0, x1, y1 = params.compute.roi_pixels(w, h)
    inside = np.zeros((h, w), bool)
    inside[y0:y1, x0:x1] = True
    for name in ("disparity", "measured", "confidence"):
        arr = getattr(res, name)
        assert arr.shape == (h, w) and arr.dtype == np.float32, name
    assert np.isnan(res.disparity[~inside]).all() and np.isnan(res.measured[~inside]).all()
    assert (res.confidence[~inside] == 0).all() and 0 <= res.confidence.min() and res.confidence.max() <= 1
    # Left of the search range nothing can be matched, as on the full frame.
    searchable = inside & (np.arange(w) >= params.sgbm.num_disparities / params.compute.scale)[None, :]
    for name in ("disparity", "measured"):
        arr = getattr(res, name)
        ok = searchable & f.branch_mask & np.isfinite(arr)
        assert ok.sum() > 0.8 * (searchable & f.branch_mask).sum() > 0, name
        assert np.median(np.abs(arr[ok] - f.disparity[ok])) < 1.0, name
    assert set(res.timings_ms) >= {"prepare", "match_left", "match_right", "wls", "assemble"}
    assert all(v >= 0 for v in res.timings_ms.values())


@pytest.mark.parametrize("key,value,base", [
    ("compute.roi", [0.2, 0.2, 0.8, 0.8], {}), ("compute.scale", 0.5, {}), ("compute.grey", True, {}),
    ("compute.wls_at", "matched", {"compute.scale": 0.5})], ids=["roi", "scale", "grey", "wls_at"])
def test_each_lever_is_live(motorcycle, key, value, base):
    """Each lever changes the disparity inside its region, so the tuner must score with it."""
    left, right, _ = motorcycle
    start = DEFAULT_PARAMS.replace(**base)
    base = DisparityPipeline(start).compute(left, right)
    changed = DisparityPipeline(start.replace(**{key: value})).compute(left, right)
    both = np.isfinite(base) & np.isfinite(changed)
    assert both.mean() > 0.2
    assert (base[both] != changed[both]).mean() > 0.01, f"{key} has no effect"


def test_scaled_disparities_come_back_in_input_pixels():
    """At half resolution SGBM sees half the disparity; the pipeline must double it back."""
    from uav_depth.sim.scene import Scene, SceneConfig

    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=0.5, branch_radius_m=0.04, seed=4)
    f = Scene(cfg).render(rng=np.random.default_rng(4))
    params = DEFAULT_PARAMS.replace(**{"compute.scale": 0.5, "sgbm.num_disparities": 48, "compute.roi": ROI})
    res = DisparityPipeline(params).run(f.left, f.right)
    ok = f.branch_mask & np.isfinite(res.measured)
    assert np.median(f.disparity[ok]) > 20     # the branch is far from the background's disparity
    assert abs(np.median(res.measured[ok] / f.disparity[ok]) - 1.0) < 0.03


def test_without_wls_the_region_path_returns_measured_and_no_confidence(small_frame):
    _, f = small_frame
    params = DEFAULT_PARAMS.replace(**{"compute.roi": ROI, "wls.enabled": False})
    res = DisparityPipeline(params).run(f.left, f.right)
    assert res.confidence is None
    assert np.array_equal(res.disparity, res.measured, equal_nan=True) and np.isfinite(res.measured).any()


@pytest.mark.parametrize("roi,min_disparity", [([0.0, 0.0, 0.2, 0.3], 0), ([0.8, 0.7, 1.0, 1.0], -16),
                                               ([0.45, 0.45, 0.46, 0.46], 0)],
                         ids=["left-edge", "right-edge-negative-min", "too-narrow"])
def test_regions_at_the_border_or_too_small_never_fail(small_frame, roi, min_disparity):
    """A region the search cannot fully cover answers NaN there instead of failing."""
    _, f = small_frame
    params = DEFAULT_PARAMS.replace(**{"compute.roi": roi, "sgbm.min_disparity": min_disparity,
                                       "compute.scale": 0.5, "sgbm.num_disparities": 64})
    res = DisparityPipeline(params).run(f.left, f.right)
    h, w = f.left.shape
    x0, _, _, _ = params.compute.roi_pixels(w, h)
    assert res.disparity.shape == (h, w)
    if x0 == 0:     # nothing left of the image to search: SGBM's own left band stays invalid
        assert np.isnan(res.disparity[:, :64]).all()
    valid = res.disparity[np.isfinite(res.disparity)]
    assert valid.size == 0 or valid.min() >= min_disparity * 2 - 1e-3


def test_3way_result_does_not_depend_on_opencv_threads(motorcycle):
    """OpenCV fixes SGBM 3-way's stripes at 4 whatever the thread count (stereosgbm.cpp, num_stripes),
    so the thread setting is a speed setting, not a parameter: a tuner worker with one thread
    scores what a two-thread daemon flies."""
    import cv2

    left, right, _ = motorcycle
    params = DEFAULT_PARAMS.replace(**{"sgbm.mode": "sgbm_3way", "compute.roi": [0.2, 0.2, 0.9, 0.9]})
    before = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = DisparityPipeline(params).run(left, right)
        cv2.setNumThreads(2)
        two = DisparityPipeline(params).run(left, right)
        cv2.setNumThreads(3)
        three = DisparityPipeline(params).run(left, right)
    finally:
        cv2.setNumThreads(before)
    # What flies (and what the flown objective scores): identical on any thread count.
    for name in ("measured", "confidence"):
        assert np.array_equal(getattr(one, name), getattr(three, name), equal_nan=True), name
    # OpenCV's WLS smoothing (the faithful mode's map) stripes by thread count: identical for one and
    # two threads; with three, a few pixels in a million differ by 1/16 px at this crop size.
    assert np.array_equal(one.disparity, two.disparity, equal_nan=True)
