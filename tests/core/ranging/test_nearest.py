"""The nearest significant object: measured pixels only, Z = f*B/d, its uncertainty, the limits and the floors."""

import math

import numpy as np
import pytest

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import ConfigError
from uav_depth.core.ranging import NEAR_END_BAND, Ranger, RangingConfig, Reason, default_roi, resolve_roi, slant
from uav_depth.sim.scene import Scene, SceneConfig

from ranging_cases import PARAMS, _result, _scene_result, ranger


@pytest.mark.parametrize("distance", [0.5, 0.8, 1.0])
@pytest.mark.parametrize("seed", [1, 2])
def test_distance_of_the_branch_within_3_percent(distance, seed):
    cfg, frame, result = _scene_result(distance, seed)
    truth = frame.nearest_branch_distance(cfg.center_roi)
    m = ranger(calib=cfg.calibration).measure(result)
    assert m.valid, m.reason
    assert m.distance_m == pytest.approx(truth, rel=0.03)
    assert 0 < m.sigma_m < 0.1 * m.distance_m and 2 <= m.quality <= 100
    x0, y0, x1, y1 = m.bbox
    ys, xs = np.nonzero(frame.branch_mask[y0:y1, x0:x1])
    assert ys.size > 0.5 * m.n_px     # the object found is the branch


def test_wls_fill_in_is_never_ranged():
    measured = np.full((360, 640), np.nan, np.float32)
    filled = np.full((360, 640), 22.0, np.float32)      # WLS filled everything in
    m = ranger().measure(_result(measured, disparity=filled, confidence=np.ones_like(filled)))
    assert not m.valid and m.reason_code is Reason.NO_OBJECT and "25 matched pixels" in m.reason


def test_low_confidence_pixels_are_not_used():
    measured = np.full((360, 640), 22.0, np.float32)
    conf = np.full_like(measured, 0.4)
    assert not ranger(RangingConfig(min_confidence=0.5)).measure(_result(measured, confidence=conf)).valid
    assert ranger(RangingConfig(min_confidence=0.3)).measure(_result(measured, confidence=conf)).valid


def test_stray_near_pixels_do_not_make_an_object():
    d = np.full((360, 640), 11.025, np.float32)     # a wall at 2 m
    d[150:152, 300:330] = 44.1                       # 60 stray pixels "at 0.5 m": fewer than min_valid_px
    m = ranger(RangingConfig(min_valid_px=100)).measure(_result(d))
    assert m.distance_m == pytest.approx(2.0, rel=1e-3)
    d[150:160, 300:330] = 44.1                       # 300 pixels: a real object
    assert ranger(RangingConfig(min_valid_px=100)).measure(_result(d)).distance_m == pytest.approx(0.5, rel=1e-3)


def test_uncertainty_from_the_disparity_spread():
    rng = np.random.default_rng(0)
    d = (22.05 + rng.normal(0, 0.6, (360, 640))).astype(np.float32)
    m = ranger(RangingConfig(cluster_depth_m=0.5, surface_quantile=0.5)).measure(_result(d))
    fb = 350.0 * 0.063
    assert m.disparity_px == pytest.approx(22.05, abs=0.03)
    assert m.sigma_px == pytest.approx(0.6, rel=0.1)
    assert m.sigma_m == pytest.approx(m.distance_m ** 2 / fb * m.sigma_px, rel=1e-6)


def test_a_perfectly_tight_cluster_still_has_the_pixel_locking_uncertainty():
    m = ranger().measure(_result(np.full((360, 640), 22.0, np.float32)))
    assert m.sigma_px == pytest.approx(1 / math.sqrt(12)) and m.sigma_m > 0


def test_farther_than_max_distance_is_no_measurement():
    d = np.full((360, 640), 350 * 0.063 / 12.0, np.float32)    # everything at 12 m
    m = ranger(RangingConfig(max_distance_m=10.0)).measure(_result(d))
    assert not m.valid


def test_limits_from_disparity_range_calibration_and_roi():
    r = ranger(RangingConfig(max_distance_m=10.0))
    fb = 350.0 * 0.063
    # min_disparity 0 + 64 - 1, less the search's last NEAR_END_BAND
    assert r.search_end_m == pytest.approx(fb / 63)
    assert r.limits.min_distance_m == pytest.approx(fb / (63 * (1 - NEAR_END_BAND)))
    assert r.limits.max_distance_m == pytest.approx(10.0)
    # the central third of 640 px at f = 350: about 2*atan(107/350)
    assert r.limits.hfov_rad == pytest.approx(2 * math.atan(106.5 / 350.0), rel=0.01)
    assert r.limits.vfov_rad == pytest.approx(2 * math.atan(60 / 350.0), rel=0.02)


def test_limits_and_uncertainty_follow_the_matching_scale():
    half = PARAMS.replace(**{"compute.scale": 0.5})
    r = ranger(params=half)
    fb = 350.0 * 0.063
    assert r.search_end_m == pytest.approx(fb / 126)               # 63 matched px are 126 input px
    assert r.limits.min_distance_m == pytest.approx(fb / (126 * (1 - NEAR_END_BAND)))
    m = r.measure(_result(np.full((360, 640), 22.0, np.float32)))
    assert m.sigma_px == pytest.approx(2 / math.sqrt(12))         # pixel locking in matched pixels


def test_flight_parameters_range_the_branch():
    """The deploy flight file's levers (centre ROI, half scale, grey, 3-way) measure as well."""
    from pathlib import Path
    from uav_depth.core.params import load_params

    flight = load_params(Path(__file__).resolve().parents[3] / "deploy" / "params-flight.yaml")
    cfg = SceneConfig(width=1280, height=720, focal_px=700.0, branch_distance_m=1.2, seed=5)
    frame = Scene(cfg).render(rng=np.random.default_rng(5))
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(
        DisparityPipeline(flight).run(frame.left, frame.right))
    assert m.valid and m.distance_m == pytest.approx(frame.nearest_branch_distance(cfg.center_roi), rel=0.03)


def test_roi_must_fit_the_image():
    assert resolve_roi(None, 640, 360) == (213, 120, 426, 240)
    with pytest.raises(ConfigError, match=r"ranging.roi must lie inside the 640x360 rectified image"):
        resolve_roi((0, 0, 700, 100), 640, 360)


def test_surface_quantile_reads_the_near_side_of_a_round_branch(monkeypatch):
    """A horizontal cylinder of radius 3 cm whose nearest surface is 1 m away fills the ROI's rows:
    over the whole band the median reads about 13% of the radius behind the surface, the default
    quantile within 1.5 mm (with the near-end window too)."""
    fb, r, zc = 350.0 * 0.063, 0.03, 1.03
    rows = 120                                           # the default ROI's rows: 120..239 of 360
    y = np.linspace(-r, r, rows, endpoint=False) + r / rows
    d = np.full((360, 640), np.nan, np.float32)
    d[120:240] = np.repeat((fb / (zc - np.sqrt(r * r - y * y)))[:, None], 640, axis=1)
    near = ranger(RangingConfig()).measure(_result(d)).distance_m
    monkeypatch.setattr(slant, "FRONT_WINDOW_MATCHED_PX", 0)     # the band's quantile alone
    median = ranger(RangingConfig(surface_quantile=0.5)).measure(_result(d)).distance_m
    assert median - 1.0 == pytest.approx(r * (1 - math.sqrt(0.75)), abs=1e-3)
    assert abs(near - 1.0) < 1.5e-3 < median - 1.0


def test_min_valid_px_counts_matched_pixels_at_any_scale():
    """At compute.scale 0.5 one matched pixel is 4 input pixels: 60 matched pixels (240 input) stay
    fewer than min_valid_px 100 (the old rule counted 240 input pixels and made them an object)."""
    half = PARAMS.replace(**{"compute.scale": 0.5})
    cfg = RangingConfig(min_valid_px=100)
    fb = 350.0 * 0.063
    d = np.full((360, 640), fb / 2.0, np.float32)       # a wall at 2 m
    d[150:162, 300:320] = fb / 0.5                       # 240 input px = 60 matched px at 0.5 m
    m = ranger(cfg, params=half).measure(_result(d))
    assert m.distance_m == pytest.approx(2.0, rel=1e-3)
    d[150:170, 300:340] = fb / 0.5                       # 800 input px = 200 matched px: an object
    assert ranger(cfg, params=half).measure(_result(d)).distance_m == pytest.approx(0.5, rel=1e-3)


def test_a_near_object_needs_its_metric_area():
    """Near the camera 100 pixels are a small area: the object must also show min_object_m2 (2 cm^2)."""
    fb = 350.0 * 0.063
    d = np.full((360, 640), fb / 2.0, np.float32)       # a wall at 2 m
    d[150:162, 300:310] = fb / 0.4                       # 120 px at 0.4 m: 120 * (0.4/350)^2 = 1.6 cm^2
    cfg = RangingConfig()
    assert cfg.min_object_m2 == pytest.approx(2e-4) and cfg.min_valid_px == 25
    m = ranger(cfg).measure(_result(d))
    assert m.distance_m == pytest.approx(2.0, rel=1e-3)
    d[150:170, 300:310] = fb / 0.4                       # 200 px: 2.6 cm^2, an object
    m = ranger(cfg).measure(_result(d))
    assert m.distance_m == pytest.approx(0.4, rel=1e-3)


def test_readings_below_the_quality_floor_are_no_measurement():
    fb = 350.0 * 0.063
    d = np.full((360, 640), np.nan, np.float32)
    d[120:150, 213:426] = fb / 1.0                       # 25 % of the ROI measured: quality 25
    m = ranger(RangingConfig(min_quality=40)).measure(_result(d))
    assert not m.valid and m.quality == 25 and m.reason_code is Reason.QUALITY_FLOOR and "40" in m.reason
    m = ranger(RangingConfig(min_quality=20)).measure(_result(d))
    assert m.valid and m.quality == 25


def test_one_definition_of_the_default_roi_and_of_a_significant_object():
    from uav_depth.core.roi import center_roi
    from uav_depth.core.significant import SIGNIFICANT_AREA_M2
    from uav_depth.sim import truth

    for w, h in ((640, 360), (1280, 720), (1001, 503)):
        assert default_roi(w, h) == center_roi(w, h) == SceneConfig(width=w, height=h).center_roi
    assert RangingConfig().min_object_m2 == SIGNIFICANT_AREA_M2 == truth.SIGNIFICANT_AREA_M2


def test_the_range_ends_where_the_sigma_floor_passes_what_the_wire_carries():
    """By default a reading is never less precise than DISTANCE_SENSOR's covariance can say (15.9 cm)."""
    from uav_depth.core.ranging import PIXEL_LOCKING_SIGMA_PX, WIRE_SIGMA_MAX_M

    fb = 350.0 * 0.063
    for params, px in ((PARAMS, 1.0), (PARAMS.replace(**{"compute.scale": 0.5}), 2.0)):
        r = ranger(RangingConfig(max_distance_m=10.0), params=params)
        z_max = math.sqrt(WIRE_SIGMA_MAX_M * fb / (PIXEL_LOCKING_SIGMA_PX * px))   # 3.49 m, 2.47 m
        assert r.limits.precise_max_m == pytest.approx(z_max) and r.limits.stated_max_m == pytest.approx(z_max)
        assert r.limits.max_distance_m == pytest.approx(10.0)       # OBSTACLE_DISTANCE's range stays
        inside = r.measure(_result(np.full((360, 640), fb / (0.97 * z_max), np.float32)))
        beyond = r.measure(_result(np.full((360, 640), fb / (1.03 * z_max), np.float32)))
        assert inside.valid and inside.sigma_m <= WIRE_SIGMA_MAX_M
        assert not beyond.valid
    # A spread wider than the floor: the reading's own sigma passes the limit nearer than that.
    rng = np.random.default_rng(0)
    d = (fb / 2.0 + rng.normal(0, 2.0, (360, 640))).astype(np.float32)     # 2 m, spread 2 px: sigma ~0.36 m
    m = ranger(RangingConfig(cluster_depth_m=1.0, surface_quantile=0.5)).measure(_result(d))
    assert not m.valid and m.reason_code is Reason.SIGMA_CEILING
    assert ranger(RangingConfig(cluster_depth_m=1.0, surface_quantile=0.5, max_sigma_m=1.0)).measure(_result(d)).valid
