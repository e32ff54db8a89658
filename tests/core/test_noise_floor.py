"""The noise floor (docs/ranging.md, *Too close*): too close needs texture that survives the sensor noise; a
featureless surface is nothing confident."""

from pathlib import Path

import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityResult, flight_pipeline
from uav_depth.core.disparity.near import NearCheck
from uav_depth.core.params import DEFAULT_PARAMS, load_params
from uav_depth.core.ranging import OutlierGate, Ranger, RangingConfig, Reason, default_roi
from uav_depth.sim.scene import Scene, SceneConfig

FLIGHT_FILE = Path(__file__).resolve().parents[2] / "deploy" / "params-flight.yaml"


def _ranger():
    calib = Calibration(focal_px=350.0, baseline_m=0.063, width=640, height=360)
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
    return Ranger(RangingConfig(), calib, default_roi(640, 360), params)


@pytest.mark.parametrize("noise_std,seed", [(2.0, 0), (2.0, 1), (4.0, 0), (4.0, 2)])
def test_a_featureless_surface_with_sensor_noise_is_nothing_confident_never_too_close(noise_std, seed):
    """A blank scene (``contrast: 0``) with sensor noise, through the flight pipeline: SGBM matches the noise,
    left-right consistent, anywhere in its search, and the thin guard (noise 2) and the near pass's rules (noise 4)
    read that as an object inside the minimum range. No texture survives the noise at the near pass's scale: the
    frame is nothing confident (a plain wall or the sky is no obstacle), and the gate keeps it so."""
    flight = load_params(FLIGHT_FILE)
    cfg = SceneConfig(contrast=0.0, noise_std=noise_std, seed=seed)
    frame = Scene(cfg).render(rng=np.random.default_rng([seed, 0]))
    r = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, flight)
    m = r.measure(flight_pipeline(flight).run(frame.left, frame.right))
    assert not m.too_close and not m.valid, m
    assert m.reason_code in (Reason.FEATURELESS, Reason.NO_OBJECT), m
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2)
    assert not gate.near(m, r.limits.min_distance_m, 0.0).too_close


def test_the_noise_floor_asks_for_texture_only_on_a_too_close_frame():
    """Maps built by hand: too-close evidence (the near pass beyond the search over a quarter of the ROI) stands on
    a region textured in the left view and falls on a featureless one; a frame that is not too close never asks
    for the texture map (it costs a frame's time)."""
    measured = np.full((360, 640), np.nan, np.float32)
    near = np.full((360, 640), np.nan, np.float32)
    near[120:156, 213:426] = 90.0                                  # 30 % of the ROI beyond the search (63 px)
    tex = np.zeros((360, 640), bool)
    tex[120:124, 213:426] = True                                   # 3.3 % of the ROI textured

    def result(left_tex):
        return DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, left_textured=left_tex))

    m = _ranger().measure(result(lambda: tex))
    assert m.too_close and m.reason_code is Reason.NEAR_PASS, m
    m = _ranger().measure(result(lambda: tex & False))
    assert not m.too_close and not m.valid and m.reason_code is Reason.FEATURELESS, m
    assert "sensor noise" in m.reason and "near pass" in m.reason

    def not_asked() -> np.ndarray:
        raise AssertionError("the left texture map is computed for too-close frames only")

    near[:] = np.nan
    m = _ranger().measure(result(not_asked))
    assert not m.too_close and m.reason_code is Reason.NO_OBJECT, m
