"""The near pass on frames narrower than its search: it sees inside the minimum range and answers the region."""

import numpy as np
import pytest

from uav_depth.core.disparity import MEASURED, DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS


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
