"""The ranging's outcomes: every one carries its reason code beside its text."""

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging import OutlierGate, RangingConfig, Reason

from ranging_cases import _result, _twig_in_front, ranger


def test_every_outcome_carries_its_reason_code_beside_its_text():
    """A reading without a distance says why as a code (what tests and benchmarks act on) and as a text (what the
    log shows); a code says whether it is too close, as the reading does. A distance carries neither."""
    from uav_depth.core.disparity.result import NearCheck
    from uav_depth.core.ranging import CHECKS, GUARDS, READING

    assert [name for name, _ in READING] == ["near check", "nearest object", "search end", "quality floor", "reading",
                                             "fine pass", "near end band", "sigma ceiling"]
    assert [name for name, _ in GUARDS] == ["thin guard"]
    assert [name for name, _ in CHECKS] == ["noise floor"]
    fb, r = 350.0 * 0.063, ranger()
    wall = np.full((360, 640), fb / 2.0, np.float32)
    piled, band, weak, floor = wall.copy(), wall.copy(), np.full_like(wall, np.nan), np.full_like(wall, np.nan)
    piled[130:230, 250:400] = 63.0
    band[130:230, 250:400] = 0.97 * 63.0
    weak[120:150, 213:426] = fb / (1.35 * r.search_end_m)
    floor[120:150, 213:426] = fb / (1.5 * r.search_end_m)
    near = np.full((360, 640), np.nan, np.float32)
    near[120:156, 213:426] = 90.0
    rng = np.random.default_rng(0)
    spread = (fb / 2.0 + rng.normal(0, 2.0, (360, 640))).astype(np.float32)
    cases = {
        None: (r, _result(wall)),
        Reason.NO_OBJECT: (r, _result(np.full((360, 640), np.nan, np.float32))),
        Reason.SEARCH_END: (r, _result(piled)),
        Reason.NEAR_END_BAND: (r, _result(band)),
        Reason.WEAK_NEAR: (r, _result(weak)),
        Reason.QUALITY_FLOOR: (r, _result(floor)),
        Reason.SIGMA_CEILING: (ranger(RangingConfig(cluster_depth_m=1.0, surface_quantile=0.5)), _result(spread)),
        Reason.NEAR_PASS: (r, DisparityResult(wall, wall, None, near=NearCheck(near, 63.0))),
        Reason.FEATURELESS: (r, DisparityResult(wall, wall, None, near=NearCheck(
            near, 63.0, left_textured=lambda: np.zeros((360, 640), bool)))),
        Reason.THIN_GUARD_TOO_CLOSE: (r, _twig_in_front(twig_d=r.fb / (1.2 * r.limits.min_distance_m))[0]),
    }
    for code, (rr, res) in cases.items():
        m = rr.measure(res)
        assert m.reason_code is code, (code, m)
        assert (m.reason is None) == (code is None) == m.valid, m
        assert code is None or m.too_close == code.too_close, m
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2)
    gate.too_close(0.3, 0.0)
    blank = gate.near(r.measure(_result(np.full((360, 640), np.nan, np.float32))), 0.3, 0.1)
    assert blank.reason_code is Reason.BLANK_AFTER_TOO_CLOSE and blank.too_close and blank.reason_code.too_close
