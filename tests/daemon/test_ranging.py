"""Branch ranging: measured pixels only, the nearest significant object, Z = f*B/d, outlier rejection."""

import functools
import math

import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.daemon.ranging import RangingConfig
from uav_depth.core.disparity import DisparityPipeline, DisparityResult
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.daemon.ranging import OutlierGate, Ranger, default_roi, resolve_roi
from uav_depth.sim.scene import Scene, SceneConfig

PARAMS = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})


@functools.lru_cache(maxsize=None)
def _scene_result(distance: float, seed: int):
    cfg = SceneConfig(width=640, height=360, focal_px=350.0, branch_distance_m=distance, seed=seed)
    frame = Scene(cfg).render(rng=np.random.default_rng(seed))
    return cfg, frame, DisparityPipeline(PARAMS).run(frame.left, frame.right)


def ranger(cfg=RangingConfig(), calib=None, roi=None, params=PARAMS):
    calib = calib or Calibration(focal_px=350.0, baseline_m=0.063, width=640, height=360)
    return Ranger(cfg, calib, roi or default_roi(calib.width, calib.height), params)


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


def _result(measured, disparity=None, confidence=None):
    measured = np.asarray(measured, np.float32)
    return DisparityResult(measured if disparity is None else disparity, measured, confidence)


def test_wls_fill_in_is_never_ranged():
    measured = np.full((360, 640), np.nan, np.float32)
    filled = np.full((360, 640), 22.0, np.float32)      # WLS filled everything in
    m = ranger().measure(_result(measured, disparity=filled, confidence=np.ones_like(filled)))
    assert not m.valid and "fewer than min_valid_px" in m.reason


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
    assert r.limits.min_distance_m == pytest.approx(fb / 63)      # min_disparity 0 + 64 - 1
    assert r.limits.max_distance_m == pytest.approx(10.0)
    # the central third of 640 px at f = 350: about 2*atan(107/350)
    assert r.limits.hfov_rad == pytest.approx(2 * math.atan(106.5 / 350.0), rel=0.01)
    assert r.limits.vfov_rad == pytest.approx(2 * math.atan(60 / 350.0), rel=0.02)


def test_limits_and_uncertainty_follow_the_matching_scale():
    half = PARAMS.replace(**{"compute.scale": 0.5})
    r = ranger(params=half)
    fb = 350.0 * 0.063
    assert r.limits.min_distance_m == pytest.approx(fb / 126)     # 63 matched px are 126 input px
    m = r.measure(_result(np.full((360, 640), 22.0, np.float32)))
    assert m.sigma_px == pytest.approx(2 / math.sqrt(12))         # pixel locking in matched pixels


def test_flight_parameters_range_the_branch():
    """The deploy flight file's levers (centre ROI, half scale, grey, 3-way) measure as well."""
    from pathlib import Path
    from uav_depth.core.params import load_params

    flight = load_params(Path(__file__).resolve().parents[2] / "deploy" / "params-flight.yaml")
    cfg = SceneConfig(width=1280, height=720, focal_px=700.0, branch_distance_m=1.2, seed=5)
    frame = Scene(cfg).render(rng=np.random.default_rng(5))
    m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight).measure(
        DisparityPipeline(flight).run(frame.left, frame.right))
    assert m.valid and m.distance_m == pytest.approx(frame.nearest_branch_distance(cfg.center_roi), rel=0.03)


def test_roi_must_fit_the_image():
    assert resolve_roi(None, 640, 360) == (213, 120, 426, 240)
    with pytest.raises(ConfigError, match=r"ranging.roi must lie inside the 640x360 rectified image"):
        resolve_roi((0, 0, 700, 100), 640, 360)


def test_outlier_gate_holds_a_single_jump_and_accepts_a_confirmed_one():
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2, forget_s=1.0)
    assert gate.accept(1.00, 0.0) and gate.accept(1.02, 0.1)
    assert not gate.accept(2.00, 0.2)          # a single-frame jump is held back
    assert gate.accept(1.01, 0.3)              # and forgotten when the next frame agrees with history
    assert not gate.accept(0.60, 0.4)
    assert gate.accept(0.61, 0.5)              # confirmed by a second frame: accepted
    assert gate.accept(3.0, 2.0)               # after forget_s without data, anything goes
    assert OutlierGate(0.0, 2).accept(1.0, 0.0) and OutlierGate(0.0, 2).accept(5.0, 0.1)


def test_surface_quantile_reads_the_near_side_of_a_round_branch():
    """A horizontal cylinder of radius 3 cm whose nearest surface is 1 m away fills the ROI's rows:
    the median reads about 13% of the radius behind the surface, the default quantile within 1.5 mm."""
    fb, r, zc = 350.0 * 0.063, 0.03, 1.03
    rows = 120                                           # the default ROI's rows: 120..239 of 360
    y = np.linspace(-r, r, rows, endpoint=False) + r / rows
    d = np.full((360, 640), np.nan, np.float32)
    d[120:240] = np.repeat((fb / (zc - np.sqrt(r * r - y * y)))[:, None], 640, axis=1)
    median = ranger(RangingConfig(surface_quantile=0.5)).measure(_result(d)).distance_m
    near = ranger(RangingConfig()).measure(_result(d)).distance_m
    assert median - 1.0 == pytest.approx(r * (1 - math.sqrt(0.75)), abs=1e-3)
    assert abs(near - 1.0) < 1.5e-3 < median - 1.0
