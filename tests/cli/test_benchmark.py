"""The daemon benchmark: structure and honesty of its figures (no timing is asserted)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from uav_depth.cli.benchmark import Variant, format_report, lever_variants, make_frames, run
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.core.params.flight import flight_params
from uav_depth.sim.scene import background_period_px


@pytest.fixture(scope="module")
def frames():
    return make_frames(3, width=320, height=180, seed=1)


def test_frames_span_the_distances_with_truth_and_no_periodic_background(frames):
    assert [round(f.design_m, 2) for f in frames] == [0.5, 1.25, 2.0]
    for f in frames:
        assert f.left.shape == (180, 320, 3) and f.right.shape == f.left.shape
        assert f.truth_m == pytest.approx(f.design_m, rel=0.02)
        assert background_period_px(f.scene) >= 200 / 1280 * 320


def test_same_seed_same_frames():
    a, b = make_frames(2, width=160, height=96, seed=5), make_frames(2, width=160, height=96, seed=5)
    assert all(np.array_equal(x.left, y.left) and x.truth_m == y.truth_m for x, y in zip(a, b))


def test_interleaved_run_reports_every_variant_on_every_frame(frames):
    variants = [Variant("naive", DEFAULT_PARAMS, 1), Variant("fast", flight_params(focal_px=175.0), 2),
                Variant("fast-1thread", flight_params(focal_px=175.0), 2, threads=1)]
    out = run(frames, variants)
    by = {v["name"]: v for v in out["variants"]}
    assert by["naive"]["runs"] == 3 and by["fast"]["runs"] == 6
    assert by["naive"]["speedup_vs_naive"] == pytest.approx(1.0)
    fast = by["fast"]
    assert fast["speedup_vs_naive"] == pytest.approx(by["naive"]["median_ms"] / fast["median_ms"])
    assert fast["p99_ms"] >= fast["median_ms"] > 0 and fast["fps"] == pytest.approx(1000 / fast["median_ms"])
    assert {"match_left", "match_right", "wls", "range"} <= set(fast["stages_median_ms"])
    # Errors are computed from the daemon's own ranging against the scene's truth.
    for v in out["variants"]:
        for pf, f in zip(v["per_frame"], frames):
            assert pf["truth_m"] == f.truth_m
            if pf["estimate_m"] is not None:
                assert pf["rel_error"] == pytest.approx((pf["estimate_m"] - f.truth_m) / f.truth_m)
        assert v["max_abs_rel_error"] is None or v["max_abs_rel_error"] >= v["median_abs_rel_error"]
    exact = out["ranging_floor"]["per_frame_estimate_m"]
    for v in out["variants"]:
        gaps = [abs(p["estimate_m"] - x) / x for p, x in zip(v["per_frame"], exact) if p["estimate_m"] and x]
        assert v["max_abs_rel_vs_exact"] == pytest.approx(max(gaps))
    # the same pipeline with one OpenCV thread estimates the same distances
    assert [p["estimate_m"] for p in by["fast"]["per_frame"]] == [p["estimate_m"]
                                                                  for p in by["fast-1thread"]["per_frame"]]


def test_ranging_floor_is_the_ranging_on_exact_disparity(frames):
    from uav_depth.cli.benchmark import ranging_floor

    floor = ranging_floor(frames)
    assert len(floor["per_frame_rel_error"]) == len(frames)
    assert all(e is not None and abs(e) < 0.2 for e in floor["per_frame_rel_error"])
    assert floor["max_abs_rel_error"] >= floor["median_abs_rel_error"] >= 0


def test_lever_ladder_adds_one_lever_at_a_time():
    flight = flight_params()
    ladder = lever_variants(flight, rounds=4, naive_rounds=1)
    names = [v.name for v in ladder]
    assert names[:8] == ["naive", "+roi", "+grey", "+3way", "+scale", "+wls@matched", "flight+WLS", "flight"]
    assert ladder[0].params == DEFAULT_PARAMS and ladder[6].params == ladder[7].params == flight
    assert not ladder[6].flies and ladder[7].flies      # as it flew before, and as it flies (no WLS smoothing)
    assert ladder[5].params.compute.wls_at == "matched" and ladder[4].params.compute.wls_at == "input"
    assert ladder[1].params.compute.roi == flight.compute.roi and ladder[1].params.compute.scale == 1.0
    assert ladder[3].params.sgbm.mode == "sgbm_3way" and not ladder[3].params.compute.scale < 1
    assert ladder[4].params.compute.scale == 0.5 and ladder[4].params.sgbm.num_disparities == 64
    assert "num_disparities=80" in ladder[7].note


def test_cli_bench_json_and_table(tmp_path):
    args = [sys.executable, "-m", "uav_depth.cli.main", "bench", "--frames", "2", "--width", "160", "--height",
            "96", "--rounds", "1", "--naive-rounds", "1"]
    proc = subprocess.run([*args, "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert [v["name"] for v in doc["variants"]] == ["naive", "flight+WLS", "flight-noSmooth", "flight"]
    wls, no_smooth = doc["variants"][1], doc["variants"][2]      # the WLS smoothing's lever alone
    assert "wls" in wls["stages_median_ms"] and "wls" not in no_smooth["stages_median_ms"]
    assert no_smooth["median_abs_rel_error"] == wls["median_abs_rel_error"]    # ranging never used the smoothing
    assert doc["machine"]["cores"] >= 1 and doc["machine"]["opencv"]
    assert "ranging_floor" in doc and doc["frames"]["n"] == 2
    table = format_report(doc)
    assert "x naive" in table and "flight" in table
    bad = subprocess.run([*args[:4], "--frames", "0"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 78 and "--frames must be at least 1, but got 0" in bad.stderr
