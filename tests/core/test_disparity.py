import warnings

import math

import numpy as np
import pytest

from uav_depth.core.disparity import MEASURED, DisparityPipeline
from uav_depth.core.errors import FrameError, ParameterWarning
from uav_depth.core.params import DEFAULT_PARAMS


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


ROI = [0.3, 0.25, 0.7, 0.75]


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


# -- one path, stage by stage -------------------------------------------------------------------------------------


def _opencv_confidence(params, left, right):
    """WLS's own left-right confidence map (0..1) for a pair matched as given."""
    import cv2

    from uav_depth.core.disparity.match import build_matchers

    m = build_matchers(params)
    l16, r16 = m.left.compute(left, right), m.right.compute(right, left)
    m.wls.filter(l16, left, disparity_map_right=r16)
    return np.clip(m.wls.getConfidenceMap() * np.float32(1.0 / 255.0), 0.0, 1.0)


@pytest.mark.parametrize("changes", [{}, {"sgbm.block_size": 3, "sgbm.mode": "sgbm_3way"},
                                     {"sgbm.min_disparity": -16, "sgbm.num_disparities": 64}],
                         ids=["baseline", "block3-3way", "negative-min"])
def test_confidence_is_opencv_wls_confidence_wherever_no_neighbour_is_unmatched(motorcycle, changes):
    """The confidence stage computes WLS's map itself (so the smoothing can be skipped): bit for bit wherever
    the depth-discontinuity boxes of the pixel and of its right partner hold no unmatched pixel; next to a
    hole ours weighs the matched neighbours only (core/disparity/confidence.py), so it differs there only."""
    import cv2

    from uav_depth.core.disparity.match import build_matchers

    left, right, _ = motorcycle
    params = DEFAULT_PARAMS.replace(**changes)
    sg = params.sgbm
    res = DisparityPipeline(params, MEASURED).run(left, right)
    opencv = _opencv_confidence(params, left, right)
    m = build_matchers(params)
    l16, r16 = m.left.compute(left, right), m.right.compute(right, left)
    k = 2 * math.ceil(0.5 * sg.block_size) + 1
    box = np.ones((k, k), np.uint8)
    left_holed = cv2.dilate((l16 < sg.min_disparity * 16).astype(np.uint8), box) > 0
    r_ok = (r16 <= -sg.min_disparity * 16) & (r16 > -(sg.min_disparity + sg.num_disparities) * 16)
    right_holed = cv2.dilate((~r_ok).astype(np.uint8), box) > 0
    h, w = l16.shape
    partner = np.clip(np.arange(w)[None, :] - (l16.astype(np.int32) >> 4), 0, w - 1)
    clean = ~left_holed & ~right_holed[np.arange(h)[:, None], partner]
    assert clean.mean() > 0.5
    assert np.array_equal(res.confidence[clean], opencv[clean])
    differ = res.confidence != opencv
    assert differ.any() and not (differ & clean).any()


def test_a_thin_object_with_a_few_unmatched_pixels_keeps_its_confidence():
    """A 9-row branch at 44 px in front of a wall at 8 px, with one unmatched pixel in every 10 of its
    columns (a saturated highlight): OpenCV counts the hole's invalid value as a disparity and weighs every
    pixel within r of it 0; weighed over its matched neighbours the branch's middle row keeps confidence."""
    from uav_depth.core.disparity.confidence import lr_confidence

    sg = DEFAULT_PARAMS.sgbm                         # block 5: a 7 x 7 box
    h, w = 40, 400
    l16 = np.full((h, w), 8 * 16, np.int16)
    l16[15:24] = 44 * 16
    l16[19, ::10] = (sg.min_disparity - 1) * 16      # the holes, on the branch's middle row
    r16 = np.full((h, w), -8 * 16, np.int16)
    r16[15:24] = -44 * 16                             # the right view agrees everywhere (left-right check)
    conf = lr_confidence(l16, r16, sg)[19, 200:300] / 255.0
    matched = l16[19, 200:300] != (sg.min_disparity - 1) * 16
    assert conf[matched].min() > 0.9


@pytest.mark.parametrize("changes", [{}, {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64},
                                     {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64,
                                      "compute.wls_at": "matched", "compute.grey": True}],
                         ids=["baseline", "roi-half-wls-input", "roi-half-wls-matched"])
def test_without_wls_measured_and_confidence_are_unchanged_and_wls_is_skipped(small_frame, changes):
    _, f = small_frame
    params = DEFAULT_PARAMS.replace(**changes)
    full = DisparityPipeline(params).run(f.left, f.right)
    lean = DisparityPipeline(params, MEASURED).run(f.left, f.right)
    if "compute.roi" not in changes:        # the full frame: the left matcher's crop is the whole image
        assert np.array_equal(full.measured, lean.measured, equal_nan=True)
        assert np.array_equal(full.confidence, lean.confidence)
    else:
        # Without the smoothing the left matcher skips the right matcher's margin: only SGBM's right-to-left
        # path differs, so the region's measured pixels and confidence stay, but for a few.
        both = np.isfinite(full.measured) & np.isfinite(lean.measured)
        answered = np.isfinite(full.measured) | np.isfinite(lean.measured)
        moved = (np.abs(full.measured - lean.measured) > 1.0)[both].sum() + (answered & ~both).sum()
        assert answered.sum() > 0 and moved / answered.sum() < 0.02
        assert (np.abs(full.confidence - lean.confidence) > 0.1).mean() < 0.02
    assert np.array_equal(lean.disparity, lean.measured, equal_nan=True)
    assert not np.array_equal(full.disparity, full.measured, equal_nan=True)    # WLS did fill in
    assert "wls" in full.timings_ms and "wls" not in lean.timings_ms


@pytest.mark.parametrize("shape", [(8, 8), (1, 1), (3, 100), (300, 8), (8, 8, 3)], ids=str)
@pytest.mark.parametrize("flight", [False, True], ids=["baseline", "flight"])
def test_images_narrower_than_the_search_give_empty_maps_not_an_opencv_error(shape, flight):
    from pathlib import Path

    from uav_depth.core.params import load_params

    path = Path(__file__).resolve().parents[2] / "deploy" / "params-flight.yaml"
    params = load_params(path) if flight else DEFAULT_PARAMS
    rng = np.random.default_rng(0)
    left, right = rng.integers(0, 256, shape, dtype=np.uint8), rng.integers(0, 256, shape, dtype=np.uint8)
    res = DisparityPipeline(params).run(left, right)
    assert res.measured.shape == shape[:2] and np.isnan(res.measured).all() and np.isnan(res.disparity).all()
    assert res.confidence is not None and not res.confidence.any()


def test_the_full_frame_is_a_window_like_any_other(small_frame):
    """A region covering the frame at full resolution computes what the default does, bit for bit."""
    from uav_depth.core.disparity.window import window

    _, f = small_frame
    h, w = f.left.shape
    win = window(DEFAULT_PARAMS, w, h)
    assert win.crop == win.region == (0, 0, w, h) and win.matched == (w, h) and not win.resized


@pytest.mark.parametrize("changes", [
    {"compute.roi": ROI},
    {"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64},
    {"compute.roi": [0.33, 0.33, 0.67, 0.67], "compute.scale": 0.5, "sgbm.num_disparities": 80, "compute.grey": True},
], ids=["roi", "roi-half", "flight-like"])
def test_every_region_pixel_is_left_right_checked(changes):
    """The right matcher leaves min_d + num_d columns at the crop's right edge unanswered: the crop
    reaches that far right of the region, so no region pixel keeps an unchecked confidence. (Before,
    26-33 % of the flight region was not left-right checked.)"""
    from uav_depth.core.disparity.window import window

    params = DEFAULT_PARAMS.replace(**changes)
    win = window(params, 1280, 720)
    band = params.sgbm.min_disparity + params.sgbm.num_disparities
    assert (win.crop[2] - win.region[2]) * params.compute.scale >= band


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


def test_confidence_over_some_columns_is_the_whole_maps_value_for_value(motorcycle):
    """lr_confidence(cols=...) computes only those columns, each as the whole map holds it."""
    from uav_depth.core.disparity.confidence import lr_confidence
    from uav_depth.core.disparity.match import build_matchers

    left, right, _ = motorcycle
    for changes in ({}, {"sgbm.min_disparity": -16, "sgbm.num_disparities": 64}):
        params = DEFAULT_PARAMS.replace(**changes)
        m = build_matchers(params)
        l16, r16 = m.left.compute(left, right), m.right.compute(right, left)
        whole = lr_confidence(l16, r16, params.sgbm)
        w = l16.shape[1]
        for c0, c1 in ((0, w), (150, 151), (200, 420), (w - 90, w)):
            part = lr_confidence(l16, r16, params.sgbm, cols=(c0, c1))
            assert np.array_equal(part[:, c0:c1], whole[:, c0:c1])
            assert not part[:, :c0].any() and not part[:, c1:].any()


def test_windows_at_a_whole_number_scale_are_multiples_of_it_and_hold_the_region():
    from uav_depth.core.disparity.window import window

    for scale, (w, h) in ((0.5, (1280, 720)), (0.25, (640, 360)), (0.125, (1280, 720)), (0.5, (333, 201))):
        params = DEFAULT_PARAMS.replace(**{"compute.scale": scale, "compute.roi": (0.33, 0.33, 0.67, 0.67)})
        win = window(params, w, h)
        k = round(1 / scale)
        cw, ch = win.crop_size
        x0, y0, x1, y1 = win.crop
        rx0, ry0, rx1, ry1 = win.region
        assert 0 <= x0 <= rx0 and rx1 <= x1 <= w and 0 <= y0 <= ry0 and ry1 <= y1 <= h
        if cw < w or w % k == 0:
            assert cw % k == 0 and win.factor == k and win.matched == (cw // k, ch // k)


def test_the_flight_maps_under_the_region_equal_the_whole_crops_resize(small_frame):
    """Measured and confidence come from the sub-block under the region: the same values a resize of the
    whole matched crop gives there (nearest: bit for bit; linear: to float rounding)."""
    import cv2

    from uav_depth.core.disparity import DisparityPipeline
    from uav_depth.core.disparity.confidence import lr_confidence
    from uav_depth.core.disparity.match import to_float
    from uav_depth.core.disparity.prepare import prepare
    from uav_depth.core.disparity.window import window

    _, f = small_frame
    params = DEFAULT_PARAMS.replace(**{"compute.roi": ROI, "compute.scale": 0.5, "sgbm.num_disparities": 64,
                                       "compute.wls_at": "matched"})
    pipe = DisparityPipeline(params, MEASURED)
    res = pipe.run(f.left, f.right)
    h, w = f.left.shape[:2]
    win = window(params, w, h)
    prep = prepare(params.compute, win, f.left, f.right)
    l16 = pipe.match._match_left(win, prep)
    r16 = pipe.match.matchers.right.compute(prep.right_m, prep.left_m)
    meas = cv2.resize(to_float(l16, 0, win.ratio), win.crop_size, interpolation=cv2.INTER_NEAREST)[win.inner()]
    conf = cv2.resize(lr_confidence(l16, r16, params.sgbm), win.crop_size, interpolation=cv2.INTER_LINEAR)
    conf = np.clip(conf[win.inner()] / 255.0, 0.0, 1.0)
    assert np.array_equal(res.measured[win.outer()], meas, equal_nan=True)
    assert np.allclose(res.confidence[win.outer()], conf, atol=1e-5)


# The near pass on frames narrower than its search (issue 11: the near pass searches up to about four times the
# main search's largest disparity at a coarse scale; SGBM answers a column only when the whole search fits beside it).

def _near_frame(width, height, focal_px, baseline_m, distance_m):
    from uav_depth.sim.sweep import VARIANTS, at_rig, render_with_truth
    cfg = at_rig(VARIANTS["plain"](distance_m, 12), width, height, focal_px, baseline_m)
    return render_with_truth(cfg)


def test_the_near_pass_sees_a_branch_inside_the_minimum_range_on_a_frame_narrower_than_its_search():
    """A Middlebury-like rig (443 x 370, f = 1247 px, B = 0.16 m): the manual baseline's 128 disparities end at
    1.571 m, and a branch at 1.40 m (142.5 px) is inside it. The near pass's window (about 4 x 127 px of search
    left of the region at 1/8 scale) is wider than the frame: unpadded, it matched nothing at all."""
    from uav_depth.core.disparity import flight_pipeline
    f, b = 1246.67, 0.16
    left, right, truth_m, (x0, y0, x1, y1) = _near_frame(443, 370, f, b, 1.40)
    res = flight_pipeline(DEFAULT_PARAMS).run(left, right)
    nd = res.near.disparity[y0:y1, x0:x1]
    beyond = np.isfinite(nd) & (nd > res.near.max_disparity_px)
    assert np.isfinite(nd).mean() > 0.8
    assert beyond.mean() > 0.25                     # the branch covers about a third of the region
    assert np.percentile(nd[beyond], 75) == pytest.approx(f * b / truth_m, rel=0.03)
    assert not (nd > np.arange(x0, x1)).any()       # no match into the padding: its partner is off the image


def test_the_near_pass_answers_the_whole_region_of_the_flight_rig():
    """At 1280 x 720 the flight file's near search did not fit left of the region: unpadded, the near pass
    answered a column only from 504 px (63 coarse px), and the region's left 78 columns were unanswered.
    Padded, its near matches cover them as the rest."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.params import load_params
    from pathlib import Path
    params = load_params(Path(__file__).parents[2] / "deploy" / "params-flight.yaml")
    left, right, truth_m, (x0, y0, x1, y1) = _near_frame(1280, 720, 700.0, 0.063, 0.20)
    res = flight_pipeline(params).run(left, right)
    nd = res.near.disparity[y0:y1, x0:x1]
    edge, rest = np.isfinite(nd[:, :100]).mean(), np.isfinite(nd[:, 100:]).mean()
    assert edge > 0.5 and edge == pytest.approx(rest, abs=0.35)


def test_the_near_pass_pads_nothing_where_its_window_fits_and_keeps_the_input_columns():
    from uav_depth.core.disparity.near import near_pad, near_params
    from uav_depth.core.params import load_params
    from pathlib import Path
    params = load_params(Path(__file__).parents[2] / "deploy" / "params-flight.yaml")
    near = near_params(params)
    assert near_pad(near, 4000, 720) == (0, 0)
    pad_l, pad_r = near_pad(near, 1280, 720)
    assert pad_l > 0 and pad_r > 0 and pad_l % 8 == 0
    from uav_depth.core.disparity import flight_pipeline
    left, right, _, _ = _near_frame(1280, 720, 700.0, 0.063, 1.0)
    res = flight_pipeline(params).run(left, right)
    assert res.near.disparity.shape == res.near.confidence().shape == left.shape[:2]


def test_the_left_right_check_alone_is_the_check_the_confidence_computes(small_frame):
    """confidence_maps(weights=False) skips the depth-edge weights (the near pass's check on every frame) and
    returns the same check, pixel for pixel, on every column range."""
    from uav_depth.core.disparity.confidence import confidence_maps
    from uav_depth.core.disparity.match import build_matchers, match_left, match_right

    _, frame = small_frame
    left, right = frame.left, frame.right
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32})
    m = build_matchers(params)
    l16, r16 = match_left(m, left, right), match_right(m, left, right)
    for cols in (None, (40, 200), (0, left.shape[1])):
        conf, lr = confidence_maps(l16, r16, params.sgbm, cols=cols)
        none, lr_only = confidence_maps(l16, r16, params.sgbm, cols=cols, weights=False)
        assert none is None
        np.testing.assert_array_equal(lr_only, lr)
        assert lr.any() and not lr.all()


@pytest.mark.parametrize("width", [1280, 4000])
def test_the_near_pass_confidence_computed_when_asked_is_the_one_computed_at_once(width):
    """The near pass leaves its confidence's weights until ranging asks (rule 4): what it then computes is the
    eager pipeline's map, padded (1280) or not (4000), and its left-right check is computed at once."""
    from pathlib import Path
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.disparity.near import NearStage, near_params, pad_views
    from uav_depth.core.disparity.prepare import grey
    from uav_depth.core.params import load_params

    params = load_params(Path(__file__).parents[2] / "deploy" / "params-flight.yaml")
    left, right, _, (x0, y0, x1, y1) = _near_frame(width, 720, 700.0 * width / 1280, 0.063, 0.20)
    res = flight_pipeline(params).run(left, right)
    assert res.near.consistent is not None and res.near.consistent.any()
    lazy = res.near.confidence()
    assert lazy is res.near.confidence()                    # computed once
    rows, pad_l, pad_r, stage = NearStage(params).for_size(width, 720)
    if rows is None:
        eager = DisparityPipeline(near_params(params), MEASURED).run(left, right)
        np.testing.assert_array_equal(lazy, eager.confidence)
        np.testing.assert_array_equal(res.near.consistent, eager.lr_consistent)
    else:        # the padded band (1280): the eager pipeline on the same mirrored rows
        band = pad_views(grey(left[rows]), grey(right[rows]), pad_l, pad_r)
        eager = DisparityPipeline(stage.params, MEASURED).run(*band)
        np.testing.assert_array_equal(lazy[rows], eager.confidence[:, pad_l:pad_l + width])
        assert not lazy[:rows.start].any() and not lazy[rows.stop:].any()
    assert lazy.shape == left.shape[:2] and (lazy[y0:y1, x0:x1] > 0.5).any()
