"""One path, stage by stage: windows, WLS's confidence, the left-right check, the flight maps under the region."""

import math

import numpy as np
import pytest

from uav_depth.core.disparity import MEASURED, DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS

from disparity_cases import ROI


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
