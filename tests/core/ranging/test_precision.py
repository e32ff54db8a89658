"""The precision rule (``ranging.max_sigma_m``): judged at the object's body, not at the near quantile it reads."""

import math

import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityResult
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.core.ranging import WIRE_SIGMA_MAX_M, Ranger, RangingConfig, Reason, default_roi

PARAMS = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
FB = 350.0 * 0.063


def ranger(cfg: RangingConfig) -> Ranger:
    calib = Calibration(focal_px=350.0, baseline_m=0.063, width=640, height=360)
    return Ranger(cfg, calib, default_roi(calib.width, calib.height), PARAMS)


def _result(measured: np.ndarray) -> DisparityResult:
    return DisparityResult(measured, measured, None)


def _branch_with_a_near_tail(body_m: float, tail_m: float, tail_share: float = 0.25):
    """A level branch across the ROI at ``body_m`` in front of a wall at 8 m, ``tail_share`` of its pixels
    (every fourth row) matched at ``tail_m``: SGBM's pixel locking, part of a surface a fraction of a pixel near."""
    d = np.full((360, 640), FB / 8.0, np.float32)
    d[160:200, 213:426] = FB / body_m
    d[160:200:round(1 / tail_share), 213:426] = FB / tail_m
    return d


def test_the_precision_is_judged_at_the_object_s_body_not_at_its_near_tail():
    """The reading leaves a fifth of the object nearer; with a quarter of its pixels locked nearer, it reads that
    tail. Beyond the stated range (3.49 m), the branch at 3.6 m would go out as 3.40 m within the wire's sigma:
    the precision is judged at its median depth, and it is no measurement. Inside the range nothing changes:
    the same tail on a branch at 3.3 m is read as before, with the reading's own sigma."""
    r = ranger(RangingConfig(max_distance_m=10.0))
    assert 3.3 < r.limits.stated_max_m < 3.5
    beyond = r.measure(_result(_branch_with_a_near_tail(3.6, 3.4)))
    assert not beyond.valid and not beyond.too_close and beyond.reason_code is Reason.SIGMA_CEILING
    assert "at the object's median depth 3.600 m above max_sigma_m" in beyond.reason
    assert "would read 3.400 m" in beyond.reason
    inside = r.measure(_result(_branch_with_a_near_tail(3.3, 3.15)))
    assert inside.valid and inside.distance_m == pytest.approx(3.15, rel=1e-4)
    assert inside.body_px == pytest.approx(FB / 3.3, rel=1e-4)
    assert inside.sigma_m == pytest.approx(3.15 ** 2 / FB / math.sqrt(12.0), rel=1e-3)
    assert inside.sigma_m <= WIRE_SIGMA_MAX_M


def _twig_with_a_near_tail(body_m: float, tail_m: float = 3.1) -> DisparityResult:
    """A confident branch at 3.45 m, 4 rows across the ROI, in front of a wall at 8 m; above it a 40 x 80 px
    twig at ``body_m`` whose matches pass the left-right check but carry no confidence (the thin guard's kind),
    a quarter of them (every fourth row) locked at ``tail_m``."""
    d = np.full((360, 640), FB / 8.0, np.float32)
    conf = np.ones_like(d)
    d[200:204, 213:426] = FB / 3.45
    d[140:180, 250:330] = FB / body_m
    d[140:180:4, 250:330] = FB / tail_m
    conf[140:180, 250:330] = 0.1
    return DisparityResult(d, d, conf, lr_consistent=np.ones(d.shape, bool))


def test_the_thin_guard_s_nearer_object_is_judged_at_its_body_too():
    """One precision rule for the confident reading and the thin guard's: a twig whose body lies beyond the stated
    range (3.65 m) but whose near tail reads 3.10 m, nearer than the 3.45 m branch, is not sent as 3.10 m (and, as
    for any imprecise nearer object, neither is the branch); with its body inside the range (3.3 m) the guard reads
    its tail, 3.10 m, with the reading's own sigma."""
    r = ranger(RangingConfig(max_distance_m=10.0))
    beyond = r.measure(_twig_with_a_near_tail(3.65))
    assert not beyond.valid and beyond.guarded and beyond.reason_code is Reason.THIN_GUARD_SIGMA
    assert "thin guard: a nearer object: sigma" in beyond.reason
    assert "at the object's median depth 3.650 m above max_sigma_m" in beyond.reason
    inside = r.measure(_twig_with_a_near_tail(3.3))
    assert inside.valid and inside.guarded and inside.distance_m == pytest.approx(3.1, rel=1e-4)
    assert inside.sigma_m == pytest.approx(3.1 ** 2 / FB / math.sqrt(12.0), rel=1e-3)
