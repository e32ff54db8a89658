"""Too close on hand-built maps: the near check's rules, each with its evidence and its threshold."""

import numpy as np
import pytest

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging import NEAR_END_BAND, RangingConfig, Reason

from ranging_cases import _result, ranger


def test_an_object_piled_at_the_end_of_the_search_is_too_close():
    fb = 350.0 * 0.063
    d = np.full((360, 640), fb / 2.0, np.float32)       # a wall at 2 m
    d[130:230, 250:400] = 63.0                           # an object at the search's last disparity (64 - 1)
    m = ranger().measure(_result(d))
    assert m.too_close and not m.valid and m.reason_code is Reason.SEARCH_END
    d[130:230, 250:400] = 61.0                           # two pixels inside the search: not piled at its end
    m = ranger().measure(_result(d))
    assert m.too_close and m.reason_code is Reason.NEAR_END_BAND     # (rule 8: in the search's last 5 %)
    d[130:230, 250:400] = 59.0                           # outside the last 5 % (59.85 px): a distance
    m = ranger().measure(_result(d))
    assert m.valid and m.distance_m == pytest.approx(fb / 59.0, rel=1e-3)


def test_near_pass_evidence_makes_too_close():
    """Result maps built by hand: the near pass matched 30 % of the ROI beyond the main search."""
    from uav_depth.core.disparity.near import NearCheck

    fb = 350.0 * 0.063
    measured = np.full((360, 640), fb / 0.5, np.float32)          # the main pass: something at 0.5 m
    near = np.full((360, 640), np.nan, np.float32)
    near[120:156, 213:426] = 90.0                                  # 30 % of the ROI's rows at 0.245 m
    res = DisparityResult(measured, measured, None, near=NearCheck(near, 63.0))
    m = ranger().measure(res)
    assert m.too_close and m.reason_code is Reason.NEAR_PASS
    near[120:132, 213:426] = 90.0
    near[132:156] = np.nan                                         # 10 %: not enough evidence
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0)))
    assert m.valid and m.distance_m == pytest.approx(0.5, rel=1e-3)


def test_a_small_near_object_the_main_pass_does_not_match_is_too_close():
    """Maps built by hand: the near pass matches 4 % of the ROI beyond the main search (a twig in front).
    Where the main pass matched none of it confidently, that is a near object: too close. Where the main
    pass matched those pixels confidently (at 0.5 m), the near matches are the false ones (a repeating
    background): a distance, not too close."""
    from uav_depth.core.disparity.near import NearCheck

    fb = 350.0 * 0.063
    measured = np.full((360, 640), fb / 0.5, np.float32)          # the main pass: something at 0.5 m
    near = np.full((360, 640), np.nan, np.float32)
    near[120:125, 213:426] = 90.0                                  # 4.2 % of the ROI at 0.245 m
    blind = measured.copy()
    blind[120:125, 213:426] = np.nan                               # ... which the main pass did not match
    m = ranger().measure(DisparityResult(blind, blind, None, near=NearCheck(near, 63.0)))
    assert m.too_close and m.reason_code is Reason.NEAR_UNCONFIRMED, m
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0)))
    assert m.valid and m.distance_m == pytest.approx(0.5, rel=1e-3)
    near[122:125] = np.nan                                         # 1.7 %: over the floor's 1.5 %
    m = ranger().measure(DisparityResult(blind, blind, None, near=NearCheck(near, 63.0)))
    assert m.too_close, m
    near[121:122] = np.nan                                         # 0.8 %: under the significance floor
    m = ranger().measure(DisparityResult(blind, blind, None, near=NearCheck(near, 63.0)))
    assert not m.too_close


def test_a_textured_region_that_nothing_matches_is_too_close():
    """Maps built by hand: a quarter of the ROI textured in both views, 1.7 % matched by either pass: an object
    nearer than either search fills the view (a few cm from the lens). Untextured (sky, a bare wall, a
    covered lens) the same blank frame is no measurement; matched over 10 % of the ROI it is not blank."""
    from uav_depth.core.disparity.near import NearCheck

    measured = np.full((360, 640), np.nan, np.float32)
    measured[120:122, 213:426] = 30.0                              # 1.7 % of the ROI matched
    near = np.full((360, 640), np.nan, np.float32)
    tex = np.zeros((360, 640), bool)
    tex[120:150, 213:426] = True                                   # 25 % of the ROI textured in both views
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, lambda: tex)))
    assert m.too_close and not m.valid and m.reason_code is Reason.BLANK_TEXTURED, m
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, lambda: tex & False)))
    assert not m.too_close and not m.valid
    measured[120:150, 213:426] = 30.0                              # 25 % matched: a scene, not a blank

    def not_asked() -> np.ndarray:
        raise AssertionError("the texture map is computed for blank frames only (it costs a frame's time)")

    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, not_asked)))
    assert not m.too_close


def test_rule_4_counts_the_near_pass_confident_matches_and_asks_for_them_only_on_a_blank_main_pass():
    """Maps built by hand. The near pass matched a quarter of the ROI inside the main search; the main pass 1.7 %.
    Confident, those matches make the frame a scene, not a blank; unconfident, the textured frame is blank: too
    close. Where the main pass alone matched enough, the near pass's confidence (its depth-edge weights cost
    about 0.3 ms a frame) is never computed."""
    from uav_depth.core.disparity.near import NearCheck

    measured = np.full((360, 640), np.nan, np.float32)
    measured[120:122, 213:426] = 30.0                              # 1.7 % of the ROI matched
    near = np.full((360, 640), np.nan, np.float32)
    near[120:150, 213:426] = 40.0                                  # 25 %, inside the main search (63 px)
    tex = np.zeros((360, 640), bool)
    tex[120:150, 213:426] = True
    ones, zeros = np.ones((360, 640), np.float32), np.zeros((360, 640), np.float32)
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, lambda: tex,
                                                                                  lambda: ones)))
    assert not m.too_close, m
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, lambda: tex,
                                                                                  lambda: zeros)))
    assert m.too_close and m.reason_code is Reason.BLANK_TEXTURED, m

    def not_asked() -> np.ndarray:
        raise AssertionError("the near confidence is computed only when the main pass matched too little")

    measured[120:150, 213:426] = 30.0                              # 25 % matched by the main pass
    m = ranger().measure(DisparityResult(measured, measured, None, near=NearCheck(near, 63.0, lambda: tex,
                                                                                  not_asked)))
    assert not m.too_close, m


def test_a_weak_reading_at_the_minimum_range_is_too_close():
    """Maps built by hand: below the quality floor, an object reading within 1.4 x the minimum range is too
    close (a twig inside the minimum range is matched, falsely and weakly, just beyond it); reading farther,
    the frame stays no measurement, and above the floor it is a distance."""
    r = ranger()
    lim = r.search_end_m                                 # the factor counts from the search's end
    fb = 350.0 * 0.063
    d = np.full((360, 640), np.nan, np.float32)
    d[120:150, 213:426] = fb / (1.35 * lim)              # 25 % of the ROI measured: quality 25, under 31
    m = r.measure(_result(d))
    assert m.too_close and not m.valid and m.reason_code is Reason.WEAK_NEAR, m
    d[120:150, 213:426] = fb / (1.5 * lim)
    m = r.measure(_result(d))
    assert not m.too_close and not m.valid and m.reason_code is Reason.QUALITY_FLOOR, m
    d[120:150, 213:426] = fb / (1.35 * lim)
    m = ranger(RangingConfig(min_quality=20)).measure(_result(d))
    assert m.valid and m.distance_m == pytest.approx(1.35 * lim, rel=1e-3)


def test_a_reading_in_the_search_s_last_5_percent_is_too_close():
    """Maps built by hand: the minimum range stated leaves out the search's last 5 % (rule 8). An object read there
    is too close, whatever its quality; one read just outside it is a distance."""
    r = ranger()
    fb = 350.0 * 0.063
    assert r.limits.min_distance_m == pytest.approx(r.search_end_m / (1 - NEAR_END_BAND))
    d = np.full((360, 640), fb / 2.0, np.float32)       # a wall at 2 m
    d[130:230, 250:400] = 0.97 * 63.0                   # 3 % short of the search's end: quality 100
    m = r.measure(_result(d))
    assert m.too_close and not m.valid and m.quality == 100 and m.reason_code is Reason.NEAR_END_BAND, m
    d[130:230, 250:400] = 0.94 * 63.0
    m = r.measure(_result(d))
    assert m.valid and m.distance_m == pytest.approx(fb / (0.94 * 63.0), rel=1e-3)
    assert m.distance_m > r.limits.min_distance_m
