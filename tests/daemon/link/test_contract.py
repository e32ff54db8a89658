"""The wire contract (pure): each condition's DISTANCE_SENSOR fields, or nothing; the conditions' table."""

import math

import pytest

from uav_depth.daemon.link.conditions import Condition, conditions_table_markdown
from uav_depth.daemon.link.contract import distance_report
from uav_depth.daemon.link.vocabulary import orientation_code
from uav_depth.core.ranging import Measurement, RangeLimits

from uav_depth.daemon.estimate import Estimate
LIMITS = RangeLimits(min_distance_m=0.345, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)


def estimate(distance=1.234, sigma=0.01, quality=80, t_capture=10.0, limits=LIMITS):
    m = Measurement(distance, sigma, quality) if distance is not None else Measurement(None, reason="none")
    return Estimate(m, limits, t_capture, t_capture + 0.05, 7, "abc")


def test_fresh_estimate_fields():
    r = distance_report(estimate(), LIMITS, now=10.25, max_age_s=0.3, t_start=9.0)
    assert r.condition == "measuring" and r.sent and r.valid
    assert r.current_distance == 123 and (r.min_distance, r.max_distance) == (33, 1000)   # min 0.345 m: 34 - 1
    assert r.covariance == 1 and r.signal_quality == 80 and r.age_ms == 250
    assert r.time_boot_ms == 1000                               # the capture time, not the send time
    assert (r.horizontal_fov, r.vertical_fov) == (0.6, 0.35)
    r = distance_report(estimate(sigma=0.05), LIMITS, now=10.1, max_age_s=0.3, t_start=9.0)
    assert r.covariance == 25                                   # (5 cm)^2


def test_a_reading_at_the_minimum_goes_out_strictly_above_min_distance():
    # issue 13 item 1: min 0.2749 m was rounded up to 28 cm and the reading to nearest (27): sent as max + 1
    lim = RangeLimits(min_distance_m=0.2749, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)
    r = distance_report(estimate(0.2749, limits=lim), lim, 10.0, 0.3)
    assert r.condition == "measuring" and r.current_distance == 27
    assert r.min_distance < r.current_distance <= r.max_distance   # PX4 needs current > min


@pytest.mark.parametrize("d,cm", [(1.2399, 123), (0.29, 29), (0.999999, 99), (2.0, 200), (0.345, 34)])
def test_readings_are_rounded_down_never_farther(d, cm):
    lim = RangeLimits(min_distance_m=0.2, max_distance_m=10.0, hfov_rad=0.6, vfov_rad=0.35)
    if d == 0.345:
        lim = LIMITS
    assert distance_report(estimate(d, limits=lim), lim, 10.0, 0.3).current_distance == cm


def test_too_close_is_the_nearest_value_both_autopilots_take_as_an_obstacle():
    est = Estimate(Measurement(None, reason="too close"), LIMITS, 10.0, 10.05, 7, "abc", too_close=True)
    r = distance_report(est, LIMITS, 10.1, 0.3)
    assert r.condition == "too close" and r.sent and not r.valid
    assert r.current_distance == r.min_distance + 1 == 34        # > min (PX4), within min..max (ArduPilot)
    assert r.current_distance <= 100 * LIMITS.min_distance_m     # never farther than the minimum range
    assert r.covariance == 255 and r.signal_quality != 1
    # a reading below the wire's minimum is too close too, never dropped to "clear"
    r = distance_report(estimate(0.30), LIMITS, 10.0, 0.3)
    assert r.condition == "too close" and r.current_distance == 34


@pytest.mark.parametrize("case,condition", [
    ("stale", "stale"), ("none", "starting"), ("no-measurement", "nothing confident"),
    ("out-of-range", "nothing confident"), ("camera lost", "camera lost"),
    ("parameters unusable", "parameters unusable"), ("shutting down", "shutting down")])
def test_blind_sends_nothing(case, condition):
    est = {"stale": estimate(t_capture=9.0), "none": None, "no-measurement": estimate(distance=None),
           "out-of-range": estimate(distance=20.0)}.get(case, estimate())
    blind = case if case in ("camera lost", "parameters unusable", "shutting down") else None
    r = distance_report(est, LIMITS, now=10.0, max_age_s=0.3, blind=blind)
    assert r.condition == condition and not r.sent and r.current_distance is None


def test_signal_quality_is_never_1():
    assert distance_report(estimate(quality=1), LIMITS, 10.0, 0.3).signal_quality == 2
    assert distance_report(estimate(quality=100), LIMITS, 10.0, 0.3).signal_quality == 100


def test_covariance_is_never_zero_and_never_smaller_than_the_sigma():
    tiny = distance_report(estimate(sigma=1e-5), LIMITS, 10.0, 0.3, 0.0)
    assert tiny.covariance == 1
    # 254 cm^2 is the largest the uint8 field carries (15.9 cm); beyond, "unknown" (255), never a
    # clipped 254 that would tell the autopilot the reading is more precise than it is.
    at_cap = distance_report(estimate(sigma=math.sqrt(254) / 100), LIMITS, 10.0, 0.3, 0.0)
    over = distance_report(estimate(sigma=0.16), LIMITS, 10.0, 0.3, 0.0)
    huge = distance_report(estimate(sigma=1.0), LIMITS, 10.0, 0.3, 0.0)
    assert at_cap.covariance == 254 and over.covariance == 255 and huge.covariance == 255
    assert over.valid and over.current_distance is not None    # the distance itself is what was measured


def test_orientation_code_rejects_nonsense():
    with pytest.raises(ValueError):
        orientation_code("sideways")
    with pytest.raises(ValueError):
        orientation_code(100)


def test_the_stated_range_ends_where_readings_stop_being_precise():
    """max_distance is the nearer of the range and the precise range (ranging.max_sigma_m)."""
    lim = RangeLimits(min_distance_m=0.345, max_distance_m=7.0, hfov_rad=0.6, vfov_rad=0.35, precise_max_m=2.4671)
    r = distance_report(estimate(distance=2.0, limits=lim), lim, 10.0, 0.3, 0.0)
    assert r.max_distance == 246 and r.valid
    beyond = distance_report(estimate(distance=2.6, limits=lim), lim, 10.0, 0.3, 0.0)
    assert not beyond.sent


@pytest.mark.parametrize("cond", list(Condition), ids=str)
def test_each_condition_sends_what_its_table_row_says(cond):
    """The table in docs/wire.md (written from Condition) and distance_report agree, condition by condition."""
    fresh = estimate(t_capture=10.0)
    est = {Condition.MEASURING: fresh, Condition.STALE: estimate(t_capture=9.0),
           Condition.NOTHING_CONFIDENT: estimate(distance=None), Condition.STARTING: None,
           Condition.TOO_CLOSE: Estimate(Measurement(None, reason="too close"), LIMITS, 10.0, 10.05, 7, "abc",
                                         too_close=True)}.get(cond, fresh)
    service_blind = cond in (Condition.CAMERA_LOST, Condition.PARAMS_UNUSABLE, Condition.SOURCE_ENDED,
                             Condition.SHUTTING_DOWN)
    r = distance_report(est, LIMITS, now=10.1, max_age_s=0.3, blind=cond if service_blind else None)
    assert r.condition is cond
    assert r.sent == cond.sends
    row = next(line for line in conditions_table_markdown().splitlines() if line.startswith(f"| {cond.value} |"))
    assert ("| **nothing**" in row) == (not cond.sends)
    text, severity = cond.statustext
    assert text.startswith("uav-depth: ") and len(text) <= 50 and severity in ("info", "warning")


@pytest.mark.parametrize("a,b,after", [(1, 0, True), (0, 1, False), (5, 5, False),
                                       (0, 2**32 - 1, True), (3, 2**32 - 10, True), (2**32 - 1, 0, False),
                                       (2**31 - 1, 0, True), (2**31 + 1, 0, False)])
def test_stamps_are_ordered_across_the_32_bit_wrap(a, b, after):
    from uav_depth.daemon.link.contract import stamp_after, stamp_before

    assert stamp_after(a, b) is after
    assert stamp_before(0) == 2**32 - 1 and stamp_after(0, stamp_before(0))
