"""The fine pass: the full-resolution re-match of the ranged object, never read farther than the coarse pass."""

import math

import numpy as np
import pytest

from uav_depth.core.disparity import DisparityResult, FineMatch
from uav_depth.core.params import load_params
from uav_depth.core.ranging import Ranger, RangingConfig, Reason
from uav_depth.sim.scene import Scene, SceneConfig

from ranging_cases import FLIGHT_FILE, PARAMS, ranger


# -- the fine pass: full-resolution re-match of the ranged object ---------------------------------------------------

HALF_FINE = PARAMS.replace(**{"compute.scale": 0.5, "compute.fine_disparities": 32})


def _coarse_wall_and_branch(branch_d: float):
    """A coarse (half-scale) map: a wall at 2 m and a branch across the ROI at disparity ``branch_d``."""
    fb = 350.0 * 0.063
    d = np.full((360, 640), fb / 2.0, np.float32)
    d[160:190, 213:426] = branch_d
    return d


class _FineAnswer:
    """A fine pass that answers ``value`` (a number, a function of the box's shape, or None: nothing matched)
    over the box asked for, and records each request in ``calls``."""

    def __init__(self, value, calls):
        self.value, self.calls = value, calls

    def match(self, box, d0):
        self.calls.append((box, d0))
        if self.value is None:
            return None
        x0, y0, x1, y1 = box
        m = np.full((y1 - y0, x1 - x0), np.nan, np.float32)
        m[...] = self.value(m.shape) if callable(self.value) else self.value
        return FineMatch(box, m, np.ones_like(m), float(d0), float(d0 + 31))


def test_the_fine_pass_replaces_a_coarse_reading_that_was_too_far():
    """Half-scale matching read the branch at 40 px; the full-resolution match of its box sees 44 px."""
    fb = 350.0 * 0.063
    calls = []

    def branch_nearer(shape):       # the box's own copy of the maps: branch rows at 44, the wall stays
        y0 = calls[-1][0][1]
        out = np.full(shape, fb / 2.0, np.float32)
        out[160 - y0:190 - y0] = 44.0
        return out

    d = _coarse_wall_and_branch(40.0)
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(branch_nearer, calls)))
    from uav_depth.core.ranging.fine import FINE_MAX_COLS, FINE_MAX_ROWS

    (box, d0), = calls
    assert box[1] <= 160 and box[3] >= 190                     # the branch's rows and a margin
    # Wider than FINE_MAX_COLS: all its 213 columns (both ends), rows cut to keep the fine pass's area.
    assert (box[0], box[2]) == (213, 426)
    assert (box[2] - box[0]) * (box[3] - box[1]) <= FINE_MAX_COLS * FINE_MAX_ROWS
    assert d0 == math.floor(40.0 - 0.25 * 32)                                      # from just below it
    assert m.refined and m.distance_m == pytest.approx(fb / 44.0, rel=1e-3)


def test_a_fine_reading_farther_than_one_coarse_pixel_does_not_replace_the_coarse_one():
    """Never farther than the coarse pass saw unless the fine match is confident: 3 px farther is not
    within the coarse pass's rounding (half a matched px = 1 input px at scale 0.5)."""
    fb = 350.0 * 0.063
    d = _coarse_wall_and_branch(40.0)
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(37.0, [])))
    assert not m.refined and m.distance_m == pytest.approx(fb / 40.0, rel=1e-3)
    # Within half a coarse pixel and measured at least as tightly: the fine reading stands.
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(39.0, [])))
    assert m.refined and m.distance_m == pytest.approx(fb / 39.0, rel=1e-3)
    # Within half a coarse pixel but spread wider than the coarse object (a third of its pixels each at 37, 38
    # and 39: it reads 39, sigma_d 1.5 px against the coarse floor 0.58): not confident.
    def split(shape):
        return (37.0 + np.indices(shape).sum(axis=0) % 3).astype(np.float32)
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(split, [])))
    assert not m.refined and m.distance_m == pytest.approx(fb / 40.0, rel=1e-3)


def test_the_fine_pass_ignores_pixels_the_coarse_pass_saw_behind_the_object():
    """The narrow fine search matches the background around the object to something inside it; pixels the
    coarse pass measured confidently behind the object do not count."""
    fb = 350.0 * 0.063
    d = _coarse_wall_and_branch(40.0)
    d[150:200, 213:426] = fb / 2.0
    d[170:180, 213:426] = 40.0                      # a thin branch; rows 150-170 and 180-200 are the wall
    calls = []

    def background_wrong(shape):                    # the fine pass: the wall rows matched at 47 px (wrong)
        y0 = calls[-1][0][1]
        out = np.full(shape, 47.0, np.float32)
        out[170 - y0:180 - y0] = 40.5
        return out

    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(background_wrong, calls)))
    box = calls[0][0]
    assert box[1] < 170 and box[3] > 180            # the box holds wall rows around the branch
    assert m.refined and m.distance_m == pytest.approx(fb / 40.5, rel=1e-3)


def test_the_fine_pass_looks_at_pixels_the_coarse_pass_did_not_measure():
    """A twig lost at half scale (unmatched rows across the branch) that the full-resolution match sees
    nearer: the fine reading takes it."""
    fb = 350.0 * 0.063
    d = _coarse_wall_and_branch(40.0)
    d[170:176, 213:426] = np.nan                    # the coarse pass matched nothing there
    calls = []

    def twig(shape):
        y0 = calls[-1][0][1]
        out = np.full(shape, 40.0, np.float32)
        out[170 - y0:176 - y0] = 50.0           # 6 cm in front of the branch
        return out

    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(twig, calls)))
    assert m.refined and m.distance_m == pytest.approx(fb / 50.0, rel=1e-3)
    d[170:176, 213:426] = fb / 2.0                  # measured confidently behind: not the object's
    calls.clear()
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(twig, calls)))
    assert m.distance_m == pytest.approx(fb / 40.0, rel=1e-3)


def test_the_fine_pass_looks_at_pixels_the_coarse_pass_measured_with_low_confidence():
    """A thin twig is all depth edge: the coarse pass may match it, but the confidence's depth-edge weight
    puts it under min_confidence (the leafy near-sweep frame at 1.5 m read 11 % farther). Its pixels are not
    the background's: the fine pass, which sees the twig nearer, takes it."""
    fb = 350.0 * 0.063
    d = _coarse_wall_and_branch(40.0)
    conf = np.ones_like(d)
    d[170:176, 213:426] = 30.0                      # matched, even behind the branch, but not confidently
    conf[170:176, 213:426] = 0.2
    calls = []

    def twig(shape):
        y0 = calls[-1][0][1]
        out = np.full(shape, 40.0, np.float32)
        out[170 - y0:176 - y0] = 50.0
        return out

    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, conf, fine=_FineAnswer(twig, calls)))
    assert m.refined and m.distance_m == pytest.approx(fb / 50.0, rel=1e-3)
    conf[170:176, 213:426] = 1.0                    # confidently behind: the background's, as before
    calls.clear()
    m = ranger(params=HALF_FINE).measure(DisparityResult(d, d, conf, fine=_FineAnswer(twig, calls)))
    assert m.distance_m == pytest.approx(fb / 40.0, rel=1e-3)


def test_the_fine_pass_looks_into_columns_the_coarse_pass_could_not_answer():
    """The band SGBM leaves unanswered at the image's left edge can hide the nearest part of the object
    (the real Cloth1 pair read 7 % farther): the fine box reaches over it."""
    fb = 350.0 * 0.063
    d = _coarse_wall_and_branch(40.0)
    d[:, :260] = np.nan                             # nothing answered left of column 260
    calls = []
    ranger(params=HALF_FINE).measure(DisparityResult(d, d, None, fine=_FineAnswer(40.0, calls)))
    assert calls[0][0][0] == 213                    # the ROI's left edge, not the coarse object's


def test_the_fine_pass_reads_a_hover_at_3_m_no_farther_than_the_coarse_pass_and_precisely_enough_for_the_wire():
    """640x360 laptop camera (f = 350 px), flight file for it: at 3 m half-scale matching leaves about 3.7
    matched px of disparity; the coarse pass read this frame 27 cm too far before the slant rule, 15 cm near
    with it and 4 cm far since unmatched neighbours no longer zero the confidence; with P1 18 (docs/ranging.md,
    *P1*) the coarse pass reads it 6 cm near and the fine pass 8 cm near. The fine pass is never farther than
    the truth by more than the coarse one is, nor 3 % from the truth either way, its error is inside two of its
    sigmas, and it is precise enough for the wire (sigma under 15.9 cm) where the coarse one is not."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.ranging import WIRE_SIGMA_MAX_M

    flight = load_params(FLIGHT_FILE.with_name("params-flight-640x360.yaml"))
    assert flight.compute.fine_disparities == 32
    cfg = SceneConfig(width=640, height=360, focal_px=350.0, baseline_m=0.063, branch_distance_m=3.0, seed=1)
    frame = Scene(cfg).render(rng=np.random.default_rng([1, 0]))
    truth = frame.truth(cfg.center_roi).significant_m
    coarse_params = flight.replace(**{"compute.fine_disparities": 0})
    # The coarse reading's sigma (0.23 m) is beyond what the wire carries: compared here with the limit raised.
    coarse = Ranger(RangingConfig(max_distance_m=7.0, max_sigma_m=1.0), cfg.calibration, cfg.center_roi,
                    coarse_params).measure(flight_pipeline(coarse_params).run(frame.left, frame.right))
    fine = Ranger(RangingConfig(max_distance_m=7.0), cfg.calibration, cfg.center_roi, flight).measure(
        flight_pipeline(flight).run(frame.left, frame.right))
    assert coarse.valid and fine.valid and fine.refined and not coarse.refined
    assert max(0.0, fine.distance_m - truth) <= max(0.0, coarse.distance_m - truth)
    assert coarse.sigma_m > WIRE_SIGMA_MAX_M >= fine.sigma_m
    assert abs(fine.distance_m - truth) < 0.03 * truth
    assert abs(fine.distance_m - truth) <= 2.0 * fine.sigma_m


def test_with_the_fine_pass_the_precise_range_follows_its_full_resolution_floor():
    """The fine pass's sigma floor is 1/sqrt(12) input px (half the coarse one at scale 0.5), so the stated
    range ends sqrt(2) farther; a reading the fine pass does not replace keeps the coarse sigma and is
    dropped beyond the coarse precise range."""
    from uav_depth.core.ranging import PIXEL_LOCKING_SIGMA_PX, WIRE_SIGMA_MAX_M

    fb = 350.0 * 0.063
    r = ranger(RangingConfig(max_distance_m=10.0), params=HALF_FINE)
    assert r.limits.precise_max_m == pytest.approx(math.sqrt(WIRE_SIGMA_MAX_M * fb / PIXEL_LOCKING_SIGMA_PX))
    z = 3.0                                                  # beyond the coarse 2.47 m, inside the fine 3.49 m
    d = np.full((360, 640), fb / z, np.float32)
    coarse_only = r.measure(DisparityResult(d, d, None, fine=_FineAnswer(None, [])))
    assert not coarse_only.valid and coarse_only.reason_code is Reason.SIGMA_CEILING
    fine = r.measure(DisparityResult(d, d, None, fine=_FineAnswer(fb / z, [])))
    assert fine.valid and fine.refined and fine.sigma_m <= WIRE_SIGMA_MAX_M
