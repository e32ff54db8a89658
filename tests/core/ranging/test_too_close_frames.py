"""Too close on rendered frames through the flight pipeline: the near pass's evidence, never a farther distance."""

import cv2
import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import MEASURED, DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS, load_params
from uav_depth.core.ranging import Ranger, RangingConfig, Reason, default_roi
from uav_depth.sim.scene import Scene, SceneConfig
from uav_depth.sim.sweep import render

from ranging_cases import FLIGHT_FILE, NEAR_PASS_RULES, _flight_frame


def test_a_branch_inside_the_minimum_range_is_too_close_never_a_farther_distance():
    """Flight file (search ending at 0.279 m at 1280x720, f = 700; minimum range 0.294 m): a branch at 0.20 m
    used to read 0.35 m."""
    from uav_depth.core.disparity import flight_pipeline

    flight = load_params(FLIGHT_FILE)
    cfg, frame = _flight_frame(0.20, 0)
    r = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight)
    assert r.search_end_m == pytest.approx(0.2791, abs=1e-4)
    assert r.limits.min_distance_m == pytest.approx(0.2938, abs=1e-4)
    m = r.measure(flight_pipeline(flight).run(frame.left, frame.right))
    assert m.too_close and m.distance_m is None, m
    assert m.reason_code in NEAR_PASS_RULES, m


def test_without_the_near_pass_the_same_frame_is_not_reported_as_a_distance_either():
    """The matcher alone (no near check) must not turn the near branch into a valid farther reading:
    the quality floor drops it (it scored 9 on this frame)."""
    flight = load_params(FLIGHT_FILE)
    cfg, frame = _flight_frame(0.20, 0)
    result = DisparityPipeline(flight, MEASURED).run(frame.left, frame.right)
    m = Ranger(RangingConfig(thin_guard_m2=0.0), cfg.calibration, cfg.center_roi, flight).measure(result)
    assert not m.valid and not m.too_close and m.reason_code is Reason.QUALITY_FLOOR
    # With the thin guard (the default) the branch's consistent matches read within 1.4 x the minimum range.
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(result)
    assert not m.valid and m.too_close and m.guarded


def test_on_a_frame_narrower_than_the_near_pass_reaches_a_branch_inside_the_minimum_range_is_too_close():
    """The real pairs' rig (443 x 370, f = 1247 px, B = 0.16 m; 128 disparities end at 1.571 m). The near pass's
    search did not fit the frame, so it matched nothing, and parameters the tuner proposed on the real pairs (seed
    2, fold 1's best) sent this 3 cm branch at 1.40 m as a valid 1.635 m (docs/ranging.md, *Too close*)."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.sim.sweep import VARIANTS, at_rig, render_with_truth

    proposed = DEFAULT_PARAMS.replace(**{"sgbm.block_size": 3, "sgbm.p1": 68, "sgbm.p2": 1027,
                                         "sgbm.disp12_max_diff": 0, "sgbm.pre_filter_cap": 117,
                                         "sgbm.uniqueness_ratio": 8, "sgbm.speckle_window_size": 60,
                                         "sgbm.speckle_range": 6})
    f = 1246.67
    left, right, truth_m, roi = render_with_truth(at_rig(VARIANTS["plain"](1.40, 12), 443, 370, f, 0.16))
    calib = Calibration(focal_px=f, baseline_m=0.16, width=443, height=370)
    for params in (proposed, DEFAULT_PARAMS):
        r = Ranger(RangingConfig(), calib, roi, params)
        assert truth_m < r.search_end_m == pytest.approx(1.571, abs=1e-3)
        m = r.measure(flight_pipeline(params).run(left, right))
        assert m.too_close and m.distance_m is None and m.reason_code in NEAR_PASS_RULES, m


def test_a_background_that_repeats_inside_the_near_search_is_not_read_as_too_close():
    """`uav-depth bench`'s fourth nominal frame: a branch at 0.91 m before the renderer's tiled background. A near
    pass that searched only beyond the main search found the tile's copy one period away (about 315 px against
    the true 7.7) on 2.9 % of the region where the main pass had no confident match, and called the frame too
    close. Searching from 0, the true match inside the main search wins."""
    from uav_depth.core.disparity import flight_pipeline

    flight = load_params(FLIGHT_FILE)
    cfg = SceneConfig(branch_distance_m=0.9090909090909091, branch_radius_m=0.04294568605940011, n_branches=2,
                      trunk_offset_m=0.35, background_distance_m=5.726907133961082, brightness=1.8296408225383942,
                      contrast=0.7104106802038302, noise_std=0.7080517201525486, blur_sigma=1.0,
                      texture_scale=1.313251813286842, color=True, seed=463327991)
    frame = Scene(cfg).render(rng=np.random.default_rng(3))
    r = Ranger(RangingConfig(), cfg.calibration, default_roi(cfg.width, cfg.height), flight)
    res = flight_pipeline(flight).run(frame.left, frame.right)
    m = r.measure(res)
    assert not m.too_close, m.reason
    truth = frame.nearest_branch_distance(default_roi(cfg.width, cfg.height))
    assert m.distance_m == pytest.approx(truth, rel=0.03)
    x0, y0, x1, y1 = r.roi
    nd = res.near.disparity[y0:y1, x0:x1]
    assert np.isfinite(nd[:, :80]).mean() > 0.5          # the columns a near search that did not fit left blank


def test_a_thin_branch_just_inside_the_minimum_range_is_too_close_on_the_near_pass_left_right_check():
    """The manual baseline's `varied` seed 0 (a 1.8 cm branch, bright exposure) at 0.33 m, 5 % inside its minimum
    range of 0.347 m. At the near pass's 1/8 scale the branch is about 5 px wide, all depth edge: its matches
    beyond the search are left-right consistent on about 11 % of the region, but the confidence's depth-edge
    roll-off weighs them 0, and judged on that confidence the frame went out as a valid 0.55 m."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.sim.sweep import VARIANTS, render_with_truth

    left, right, truth_m, roi = render_with_truth(VARIANTS["varied"](0.33, 0))
    cfg = VARIANTS["varied"](0.33, 0)
    r = Ranger(RangingConfig(), cfg.calibration, roi, DEFAULT_PARAMS)
    assert truth_m < r.limits.min_distance_m
    res = flight_pipeline(DEFAULT_PARAMS).run(left, right)
    m = r.measure(res)
    assert m.too_close and m.distance_m is None and m.reason_code in NEAR_PASS_RULES, m
    x0, y0, x1, y1 = roi
    with np.errstate(invalid="ignore"):
        beyond = res.near.consistent[y0:y1, x0:x1] & (res.near.disparity[y0:y1, x0:x1] > r.d_max)
    assert beyond.mean() > 0.05
    assert (res.near.confidence()[y0:y1, x0:x1][beyond] >= RangingConfig().min_confidence).mean() < 0.1


def test_the_near_pass_confidence_does_not_depend_on_where_wls_would_filter():
    """compute.wls_at says where WLS would smooth the main map (the tuner's faithful mode). The near pass has no
    WLS: at its 1/8 scale, 'input' made its left-right tolerance 0.19 px and its depth-edge roll-off 63 x
    steeper, so the manual baseline's near matches had no confidence at all."""
    from uav_depth.core.disparity import flight_pipeline

    cfg, frame = _flight_frame(0.20, 0)
    a = flight_pipeline(DEFAULT_PARAMS).run(frame.left, frame.right)
    b = flight_pipeline(DEFAULT_PARAMS.replace(**{"compute.wls_at": "matched"})).run(frame.left, frame.right)
    np.testing.assert_array_equal(a.near.confidence(), b.near.confidence())
    assert (a.near.confidence() >= 0.5).mean() > 0.05


def test_the_flight_pipeline_still_ranges_a_branch_just_outside_the_minimum_range():
    from uav_depth.core.disparity import flight_pipeline

    flight = load_params(FLIGHT_FILE)
    cfg, frame = _flight_frame(0.30, 0)
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(
        flight_pipeline(flight).run(frame.left, frame.right))
    assert m.valid and not m.too_close and m.distance_m == pytest.approx(0.30, rel=0.02)


@pytest.mark.parametrize("distance", [0.29, 0.30])
def test_the_baseline_never_reads_a_branch_inside_its_minimum_range_farther(distance):
    """The manual baseline (minimum range 0.347 m) on the near sweep's ``varied`` seed 0: a branch at
    0.25-0.32 m used to go out as 0.48-0.55 m, valid (quality 36-46); the near pass sees it beyond the
    search where the main pass matched nothing: too close. At 0.30 m it sees 1.9 % of the region so
    (the floor was 2 % until 2026-12-04, and the frame went out as 0.53 m)."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.sim.scene import vary

    cfg = vary(SceneConfig(), np.random.default_rng([0, 101]), branch_distance_m=distance)
    frame = render(cfg)   # the near sweep's frame (bench/near_sweep.py)
    r = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, DEFAULT_PARAMS)
    m = r.measure(flight_pipeline(DEFAULT_PARAMS).run(frame.left, frame.right))
    assert m.too_close and not m.valid, m


@pytest.mark.parametrize("variant,seed,distance", [("plain", 0, 0.05), ("plain", 1, 0.07), ("varied", 1, 0.05),
                                                   ("leafy", 0, 0.05)])
def test_a_branch_a_few_centimetres_from_the_lens_is_too_close(variant, seed, distance):
    """Nearer than the near pass can match (below 0.09 m with the flight file at 1280x720) the branch's other
    view lies outside the right image: these frames were no measurement (quality 2-5), a single one could
    not be told from sky. Both views are textured and nothing matches: too close, for both parameter sets."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.params import DEFAULT_PARAMS
    from uav_depth.sim.scene import vary

    cfg = {"plain": lambda: SceneConfig(seed=seed, branch_distance_m=distance, branch_radius_m=0.03),
           "varied": lambda: vary(SceneConfig(), np.random.default_rng([seed, 101]), branch_distance_m=distance),
           "leafy": lambda: SceneConfig.leafy(seed=seed, branch_distance_m=distance)}[variant]()
    frame = Scene(cfg).render(rng=np.random.default_rng(seed))
    for params in (load_params(FLIGHT_FILE), DEFAULT_PARAMS):
        r = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, params)
        m = r.measure(flight_pipeline(params).run(frame.left, frame.right))
        assert m.too_close and not m.valid, m


def test_a_sky_like_noisy_frame_is_not_too_close():
    """A smooth ramp with heavy noise (8 grey levels) in both views, nothing else: not textured at the near
    pass's scale, so a blank frame stays no measurement, never too close."""
    from uav_depth.core.disparity import flight_pipeline

    rng = np.random.default_rng(0)
    flight = load_params(FLIGHT_FILE)
    cfg = SceneConfig()

    def view():
        g = np.tile(np.linspace(150, 170, 1280, dtype=np.float32), (720, 1)) + rng.normal(0, 8, (720, 1280))
        return cv2.cvtColor(np.clip(g, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)

    result = flight_pipeline(flight).run(view(), view())
    assert result.near.textured is not None
    x0, y0, x1, y1 = cfg.center_roi
    assert result.near.textured()[y0:y1, x0:x1].mean() < 0.005
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(result)
    assert not m.too_close


def test_a_weak_twig_inside_the_minimum_range_is_too_close():
    """The flight file on the near sweep's leafy seed 0 with the target at 0.32 m: the nearest twig is at 0.21 m,
    inside the minimum range (0.279 m); it was matched just beyond it, weakly (quality 17, 0.30 m), and the
    frame went out as no measurement. Now too close."""
    from uav_depth.core.disparity import flight_pipeline

    flight = load_params(FLIGHT_FILE)
    cfg = SceneConfig.leafy(seed=0, branch_distance_m=0.32)
    frame = render(cfg)   # the near sweep's frame (bench/near_sweep.py)
    assert frame.truth(cfg.center_roi).significant_m < 0.279
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(
        flight_pipeline(flight).run(frame.left, frame.right))
    assert m.too_close and not m.valid, m


def test_a_twig_inside_the_minimum_range_read_just_beyond_it_is_too_close():
    """The manual baseline on the near sweep's leafy seed 10 with the target at 0.40 m: the nearest twig is at
    0.285 m, 18 % inside the search's end (0.347 m); matched falsely at 1.008 x that, with quality 33 (above the
    floor), it went out as a valid 0.35 m. Now too close (rule 8)."""
    from uav_depth.core.disparity import flight_pipeline

    cfg = SceneConfig.leafy(seed=10, branch_distance_m=0.40)
    frame = render(cfg)   # the near sweep's frame (bench/near_sweep.py)
    r = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, DEFAULT_PARAMS)
    assert frame.truth(cfg.center_roi).significant_m < 0.9 * r.search_end_m
    m = r.measure(flight_pipeline(DEFAULT_PARAMS).run(frame.left, frame.right))
    assert m.too_close and not m.valid and m.reason_code is Reason.NEAR_END_BAND, m
    # what it read: just beyond the search's end, inside the minimum range stated
    assert r.search_end_m < cfg.focal_px * cfg.baseline_m / m.disparity_px < r.limits.min_distance_m, m


@pytest.mark.parametrize("distance", [0.27, 0.29])
def test_a_tuned_file_cannot_tune_the_near_pass_away(distance):
    """A file `uav-depth tune` wrote on real pairs (2026-12-05: uniqueness 0, speckle window 2670 / range 6,
    disp12_max_diff 628) gave the near pass those match filters too: they erased its matches beyond the search,
    and the near sweep's `varied` seed 0 branch at 0.27 / 0.29 m, inside the minimum range of 0.347 m, went out
    as 0.50 / 0.51 m. The near pass keeps its own filters (near.NEAR_FILTERS): too close."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.disparity.near import NEAR_FILTERS, near_params
    from uav_depth.sim.sweep import VARIANTS, render_with_truth

    tuned = DEFAULT_PARAMS.replace(**{"sgbm.block_size": 1, "sgbm.p1": 9, "sgbm.p2": 21, "sgbm.disp12_max_diff": 628,
                                      "sgbm.pre_filter_cap": 16, "sgbm.uniqueness_ratio": 0,
                                      "sgbm.speckle_window_size": 2670, "sgbm.speckle_range": 6})
    assert near_params(tuned) == near_params(DEFAULT_PARAMS.replace(**{"sgbm.block_size": 1, "sgbm.p1": 9,
                                                                         "sgbm.p2": 21}))
    assert all(near_params(tuned).get(k) == v for k, v in NEAR_FILTERS.items())
    cfg = VARIANTS["varied"](distance, 0)
    left, right, truth_m, roi = render_with_truth(cfg)
    r = Ranger(RangingConfig(), cfg.calibration, roi, tuned)
    assert truth_m < 0.95 * r.limits.min_distance_m
    m = r.measure(flight_pipeline(tuned).run(left, right))
    assert m.too_close and m.distance_m is None, m
