"""sim.sweep: the near sweep's scenes, at any rig (bench/near_sweep.py and tune's safety sweep)."""

from __future__ import annotations

import math

from uav_depth.sim.scene import SceneConfig
from uav_depth.sim.sweep import (GUIDE_SEEDS, QUICK_DISTANCES, QUICK_SEEDS, RENDERED, SAFETY_DISTANCES, SAFETY_SEEDS,
                                 SWEEPS, VARIANTS, at_rig, quick_sweep, render_with_truth, safety_sweep,
                                 search_guide)


def test_the_quick_sweep_covers_every_variant_seed_and_distance_once_at_the_rig_asked():
    scenes = list(quick_sweep(640, 360, 350.0, 0.12))
    assert len(scenes) == len(VARIANTS) * len(QUICK_SEEDS) * len(QUICK_DISTANCES) == 84
    assert len({k for k, _ in scenes}) == 84
    assert all((c.width, c.height, c.focal_px, c.baseline_m) == (640, 360, 350.0, 0.12) for _, c in scenes)
    assert {c.branch_distance_m for _, c in scenes} == set(QUICK_DISTANCES)
    default = dict(quick_sweep())["plain-s0-1.00m"]
    assert (default.width, default.focal_px) == (SceneConfig().width, SceneConfig().focal_px)


def test_the_safety_sweep_reaches_across_the_working_range_on_seeds_the_benchmarks_do_not_use():
    """tune's default sweep: inside and across the minimum range as the quick sweep, then every 20 cm to 3 m;
    seeds 10-14, none of bench/near_sweep.py's 0-9, so the near sweep stays a check the tuner never saw."""
    scenes = list(safety_sweep(640, 360, 350.0, 0.12))
    assert len(scenes) == len({k for k, _ in scenes}) == 330
    dists = sorted({c.branch_distance_m for _, c in scenes})
    assert dists[:8] == sorted(QUICK_DISTANCES[:8]) and max(dists) == 3.0
    assert [round(b - a, 2) for a, b in zip(dists[8:], dists[9:])] == [0.2] * 13
    assert set(SAFETY_SEEDS).isdisjoint(range(10))
    assert {k.split("-")[1] for k, _ in scenes} == {f"s{seed}" for seed in SAFETY_SEEDS}
    assert {c.seed for k, c in scenes if k.startswith("leafy")} == set(SAFETY_SEEDS)
    assert all((c.width, c.focal_px) == (640, 350.0) for _, c in scenes)
    assert set(SWEEPS) == {"standard", "quick"} and len(SAFETY_DISTANCES) == 22


def test_the_search_guide_is_branches_across_the_working_range_on_seeds_no_check_uses():
    """tune's search guide: every 20 cm from 0.4 to 3 m, leafy scenes (where candidates read branches farther) on
    three seeds, plain and varied on one; seeds 20-22: none of the safety sweep's, which judges what the guide led
    to, nor the benchmarks'."""
    scenes = list(search_guide(640, 480, 500.0, 0.06))
    assert len(scenes) == len({k for k, _ in scenes}) == 70
    by_variant = {v: {int(k.split("-")[1][1:]) for k, _ in scenes if k.startswith(v + "-")} for v in VARIANTS}
    assert by_variant == {"plain": {20}, "varied": {20}, "leafy": {20, 21, 22}} == {
        v: set(s) for v, s in GUIDE_SEEDS.items()}
    dists = sorted({c.branch_distance_m for _, c in scenes})
    assert dists[0] == 0.4 and dists[-1] == 3.0 and len(dists) == 14
    seeds = set().union(*by_variant.values())
    assert seeds.isdisjoint(SAFETY_SEEDS) and seeds.isdisjoint(range(10))
    assert all((c.width, c.height, c.focal_px, c.baseline_m) == (640, 480, 500.0, 0.06) for _, c in scenes)
    assert set(RENDERED) == set(SWEEPS) | {"guide"} and "guide" not in SWEEPS


def test_at_rig_keeps_the_scene_in_metres():
    leafy = VARIANTS["leafy"](0.8, 3)
    small = at_rig(leafy, 320, 180, 175.0, 0.063)
    assert small.branch_distance_m == leafy.branch_distance_m and small.seed == leafy.seed
    assert small.rect_error_px == leafy.rect_error_px and small.width == 320


def test_render_with_truth_gives_the_nearest_significant_object_in_the_centre_region():
    cfg = at_rig(VARIANTS["plain"](0.6, 0), 320, 180, 175.0, 0.063)
    left, right, truth_m, roi = render_with_truth(cfg)
    assert left.shape == right.shape == (180, 320)
    assert roi == cfg.center_roi
    # the 3 cm branch's near surface, at its axis distance less about its radius
    assert math.isfinite(truth_m) and 0.55 < truth_m <= 0.6
