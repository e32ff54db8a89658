"""Near sweep: branch distances from 0.05 m to the flight file's far working distance, every frame judged on the wire.

For each parameter set (manual baseline = core.params DEFAULT_PARAMS, and
deploy/params-flight.yaml), each scene variant and seed, a branch is placed at
every distance of the sweep (1 cm steps by default) on 1280x720 synthetic pairs
(focal 700 px, baseline 63 mm) and measured as the daemon does: the real
pipeline, ``core.ranging.Ranger`` and ``link.contract.distance_report``. The truth is
the nearest significant object in the ranging region (sim/truth.py: at least 3 mm
thick, at least 2 cm^2 visible; docs/scenes.md).

Variants: ``plain`` (the issue's reproduction: SceneConfig(seed, branch_distance_m=d,
branch_radius_m=0.03)), ``varied`` (``vary``: imaging conditions and geometry drawn
per seed) and ``leafy`` (``SceneConfig.leafy``: twigs, needles and a small branch in
front, sky, shadows, the eyes' differences).

Printed per parameter set: frames; frames whose truth lies inside the minimum range
and how many of them were reported too close / sent as a valid distance; frames
reported farther than the truth by more than 2 % (valid distances only); median and
worst error of the valid distances (signed, relative to the truth); frames without a
measurement. Then the farther readings by the width of the truth object at the input
resolution (f x thickness / distance: is a miss a twig too thin for the camera?) and by its
orientation in the image (a stereo rig with a horizontal baseline matches along rows, so a
near-horizontal twig is the textbook hard case: is that what is missed?).
Renders are cached in /tmp/uav-depth-scene-cache (UAV_DEPTH_SCENE_CACHE),
about 1.8 MB a frame, shared by both parameter sets and by reruns.

    .venv/bin/python bench/near_sweep.py --quick            # 14 distances x 2 seeds x 3 variants
    .venv/bin/python bench/near_sweep.py                    # the full sweep (296 distances x 5 seeds x 3)
    .venv/bin/python bench/near_sweep.py --min-m 0.05 --max-m 0.4 --params flight --json
    .venv/bin/python bench/near_sweep.py --first-seed 10 --step-m 0.05 --params flight --flight-file tuned.yaml
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import scenebench
from scenebench import (PARAM_SET_NAMES, Measurer, add_ranging_args, flight_max_range_m, fmt_pct, param_sets,
                        ranging_config, rel_err, render_cached)

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.ranging import RangingConfig
from uav_depth.sim.scene import SceneConfig
from uav_depth.sim.sweep import QUICK_DISTANCES, VARIANTS

FARTHER_TOL = 0.02


def distances(min_m: float, max_m: float, step_m: float) -> list[float]:
    n = int(math.floor((max_m - min_m) / step_m + 1e-9))
    return [round(min_m + i * step_m, 4) for i in range(n + 1)]


def width_px(thickness_m: float, distance_m: float, focal_px: float) -> float:
    """How many input pixels across the truth object is: f x thickness / distance (inf: the background plane)."""
    if not (math.isfinite(distance_m) and distance_m > 0) or math.isnan(thickness_m):
        return math.nan
    return math.inf if math.isinf(thickness_m) else focal_px * thickness_m / distance_m


def truth_angle_deg(disparity: np.ndarray, roi: tuple[int, int, int, int], truth_m: float,
                    focal_px: float, baseline_m: float) -> float:
    """The truth object's orientation in the image, degrees from the rows (0: horizontal, 90: vertical); NaN when
    there is no truth or its pixels do not make a line.

    Its pixels: those of the exact disparity in the region within 10 % of the truth's, the largest 8-connected
    piece among those holding a pixel within 1 % of it (a twig in front of the target lies at least about 10 %
    nearer). The angle is that of the piece's principal axis (second moments of its pixel positions)."""
    if not (math.isfinite(truth_m) and truth_m > 0):
        return math.nan
    x0, y0, x1, y1 = roi
    ex = np.asarray(disparity, np.float32)[y0:y1, x0:x1]
    d = focal_px * baseline_m / truth_m
    with np.errstate(invalid="ignore"):
        off = np.abs(ex - d)
        seed = off < 0.01 * d
        if not seed.any():
            return math.nan
        _, lab = cv2.connectedComponents((off < 0.1 * d).astype(np.uint8), connectivity=8)
    ys, xs = np.nonzero(lab == np.bincount(lab[seed]).argmax())
    if ys.size < 3:
        return math.nan
    w, vec = np.linalg.eigh(np.cov(np.vstack([xs, ys]).astype(np.float64)))
    if not w[1] > 0:
        return math.nan
    ang = math.degrees(math.atan2(vec[1, 1], vec[0, 1])) % 180.0
    return min(ang, 180.0 - ang)


#: Bins of the truth object's width at the input resolution, px (by_width): a twig of w m at Z m spans f w / Z.
WIDTH_BINS = (0.0, 1.5, 2.0, 3.0, 5.0, 10.0, math.inf)
#: Bins of its orientation, degrees from the rows (by_angle).
ANGLE_BINS = (0.0, 15.0, 45.0, 90.01)


def by_bins(rows: list[dict[str, Any]], key: str, bins: tuple[float, ...]) -> list[dict[str, Any]]:
    """Per parameter set and bin of ``key`` (a row's number): in-range frames, how many were sent as a distance,
    and how many of them read farther than the truth by more than 2 % and 5 %."""
    out = []
    for name in dict.fromkeys(r["params"] for r in rows):
        for lo, hi in zip(bins[:-1], bins[1:]):
            rs = [r for r in rows if r["params"] == name and not r["inside_min"] and lo <= r[key] < hi]
            if not rs:
                continue
            out.append({"params": name, "lo": lo, "hi": hi, "frames_in_range": len(rs),
                        "sent_valid": sum(r["reported_m"] is not None for r in rs),
                        "farther_2pct": sum(r["farther"] for r in rs),
                        "farther_5pct": sum(r["err"] is not None and r["err"] > 0.05 for r in rs)})
    return out


def by_width(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """:func:`by_bins` of the truth object's width (input px). The background plane and the target branch fall
    in the last bins; twigs at the resolution limit in the first."""
    return by_bins(rows, "truth_width_px", WIDTH_BINS)


def by_angle(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """:func:`by_bins` of the truth object's orientation (degrees from the rows, :func:`truth_angle_deg`)."""
    return by_bins(rows, "truth_angle_deg", ANGLE_BINS)


def format_bins_table(rows: list[dict[str, Any]], title: str, unit: str) -> str:
    head = f"{'params':9s} {unit:>10s} {'in range':>8s} {'sent':>6s} {'farther>2%':>10s} {'>5%':>5s} {'share>2%':>8s}"
    lines = [title, head, "-" * len(head)]
    for r in rows:
        share = f"{100 * r['farther_2pct'] / r['sent_valid']:.1f}%" if r["sent_valid"] else "-"
        lines.append(f"{r['params']:9s} {r['lo']:4g}-{r['hi']:<5g} {r['frames_in_range']:8d} {r['sent_valid']:6d} "
                     f"{r['farther_2pct']:10d} {r['farther_5pct']:5d} {share:>8s}")
    lines.append("share>2%: of the frames sent as a distance")
    return "\n".join(lines)


def format_width_table(rows: list[dict[str, Any]]) -> str:
    return format_bins_table(rows, "by the truth object's width at the input resolution (f x thickness / distance; "
                                   "inf: background)", "width px")


def format_angle_table(rows: list[dict[str, Any]]) -> str:
    return format_bins_table(rows, "by the truth object's orientation in the image (degrees from the rows: 0 "
                                   "horizontal, 90 vertical)", "angle deg")


def sweep(dists, seeds, variants=tuple(VARIANTS), params_names=("baseline", "flight"), cache: bool = True,
          progress: bool = False, ranging: RangingConfig | None = None) -> list[dict[str, Any]]:
    """One row per (parameter set, variant, seed, distance): truth, what the wire says, the judgement."""
    sets = param_sets(params_names)
    rows = []
    cal_cfg = SceneConfig()
    measurers = {name: Measurer(p, cal_cfg, ranging) for name, p in sets.items()}
    t0 = time.monotonic()
    total = len(variants) * len(seeds) * len(dists)
    done = 0
    for variant in variants:
        for seed in seeds:
            for d in dists:
                cfg = VARIANTS[variant](d, seed)
                frame = render_cached(cfg, cache)
                angle = truth_angle_deg(frame.disparity, cfg.center_roi, frame.truth_m, cfg.focal_px, cfg.baseline_m)
                for name, meas in measurers.items():
                    out = meas.measure(frame.left, frame.right)
                    inside = frame.truth_m < meas.min_range_m
                    err = rel_err(out["reported_m"], frame.truth_m)
                    out["exact_err"] = rel_err(meas.measure_exact(frame.disparity), frame.truth_m)
                    rows.append({"params": name, "variant": variant, "seed": seed, "distance_m": d,
                                 "truth_m": frame.truth_m, "nearest_any_m": frame.nearest_any_m,
                                 "truth_thickness_m": frame.truth_thickness_m,
                                 "truth_width_px": width_px(frame.truth_thickness_m, frame.truth_m, cfg.focal_px),
                                 "truth_angle_deg": angle,
                                 "min_range_m": meas.min_range_m, "inside_min": bool(inside), **out, "err": err,
                                 "farther": bool(err is not None and err > FARTHER_TOL)})
                done += 1
                if progress and done % 20 == 0:
                    el = time.monotonic() - t0
                    print(f"  ... {done}/{total} frames, {el:.0f} s, eta {el / done * (total - done):.0f} s",
                          file=sys.stderr, flush=True)
    return rows


def summarize(rows: list[dict[str, Any]], by_variant: bool = True) -> list[dict[str, Any]]:
    """Per parameter set over all variants ("all"), then per (parameter set, variant)."""
    groups = [(name, "all") for name in dict.fromkeys(r["params"] for r in rows)]
    if by_variant:
        groups += list(dict.fromkeys((r["params"], r["variant"]) for r in rows))
    out = []
    for name, variant in groups:
        rs = [r for r in rows if r["params"] == name and variant in ("all", r["variant"])]
        inside = [r for r in rs if r["inside_min"]]
        errs = [r["err"] for r in rs if r["err"] is not None and not r["inside_min"]]
        worst = max(errs, key=abs) if errs else None
        out.append({
            "params": name, "variant": variant, "frames": len(rs), "min_range_m": rs[0]["min_range_m"],
            "inside_min": len(inside), "inside_min_too_close": sum(r["too_close"] for r in inside),
            "inside_min_sent_valid": sum(r["reported_m"] is not None for r in inside),
            "too_close_in_range": sum(r["too_close"] for r in rs if not r["inside_min"]),
            "farther_2pct": sum(r["farther"] for r in rs),
            "farther_5pct": sum(r["err"] is not None and r["err"] > 0.05 for r in rs),
            "nearer_5pct": sum(r["err"] is not None and r["err"] < -0.05 for r in rs if not r["inside_min"]),
            "farther_2pct_inside_min": sum(r["farther"] for r in inside),
            "median_abs_err": float(np.median(np.abs(errs))) if errs else None,
            "exact_farther_2pct": sum(r["exact_err"] is not None and r["exact_err"] > FARTHER_TOL
                                      for r in rs if not r["inside_min"]),
            "worst_err": worst,
            "no_measurement": sum(r["reported_m"] is None and not r["too_close"] for r in rs if not r["inside_min"]),
            "frames_in_range": len(rs) - len(inside),
        })
    return out


def format_table(summary: list[dict[str, Any]]) -> str:
    head = (f"{'params':9s} {'variant':7s} {'frames':>6s} {'min m':>6s} {'inside':>6s} {'too close':>9s} {'sent valid':>10s} "
            f"{'farther>2%':>10s} {'>5%':>4s} {'nearer>5%':>9s} {'median|e|':>9s} {'worst':>8s} {'no meas':>7s} {'close!':>6s} {'exact>2%':>8s}")
    lines = [head, "-" * len(head)]
    for s in summary:
        lines.append(f"{s['params']:9s} {s['variant']:7s} {s['frames']:6d} {s['min_range_m']:6.3f} {s['inside_min']:6d} "
                     f"{s['inside_min_too_close']:9d} {s['inside_min_sent_valid']:10d} {s['farther_2pct']:10d} "
                     f"{s['farther_5pct']:4d} {s['nearer_5pct']:9d} "
                     f"{fmt_pct(s['median_abs_err']):>9s} {fmt_pct(s['worst_err']):>8s} {s['no_measurement']:7d} {s['too_close_in_range']:6d} "
                     f"{s['exact_farther_2pct']:8d}")
    lines.append("inside: truth nearer than the minimum range; too close / sent valid: of those; farther>2%: valid "
                 "distance > 1.02 x truth (all frames), >5%: > 1.05 x; nearer>5%: in range, < 0.95 x; median/worst: valid distances in range; no meas: in range;\n"
                 "close!: in range but sent as too close (safe, not the truth); "
                 "exact>2%: in range, the same ranging on the exact disparity farther than truth by > 2% (the ranging's own)")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help=f"distances {QUICK_DISTANCES}, seeds 0-1")
    ap.add_argument("--min-m", type=float, default=0.05)
    ap.add_argument("--max-m", type=float, default=None, help="default: the flight file's far working distance")
    ap.add_argument("--step-m", type=float, default=0.01)
    ap.add_argument("--seeds", type=int, default=5, help="how many seeds (default 5)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="seeds FIRST .. FIRST + SEEDS - 1 (default 0; the shipped files and the ranging rules were "
                         "developed on 0-4, uav-depth tune's safety sweep uses 10-14)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--params", nargs="+", default=["baseline", "flight"], choices=PARAM_SET_NAMES)
    ap.add_argument("--flight-file", type=Path, default=None,
                    help="measure this parameter file as the 'flight' set (e.g. a tuned candidate; with --max-m)")
    ap.add_argument("--no-cache", action="store_true")
    ap.add_argument("--json", action="store_true", help="print rows and summary as JSON instead of the table")
    add_ranging_args(ap)
    ap.add_argument("--per-distance", action="store_true", help="also print one line per distance")
    args = ap.parse_args(argv)
    if args.flight_file is not None:
        scenebench.FLIGHT_FILE = args.flight_file
    max_m = args.max_m if args.max_m is not None else flight_max_range_m()
    dists = list(QUICK_DISTANCES) if args.quick else distances(args.min_m, max_m, args.step_m)
    seeds = list(range(2)) if args.quick else list(range(args.first_seed, args.first_seed + args.seeds))
    rows = sweep(dists, seeds, args.variants, args.params, cache=not args.no_cache, progress=not args.json,
                 ranging=ranging_config(args.thin_guard_cm2))
    summary = summarize(rows)
    widths, angles = by_width(rows), by_angle(rows)
    if args.json:
        print(json.dumps({"summary": summary, "by_width": widths, "by_angle": angles, "rows": rows}, indent=1))
        return
    print(machine_line())
    print(f"near sweep: {len(dists)} distances {dists[0]:.2f}..{dists[-1]:.2f} m, seeds {seeds}, variants "
          f"{args.variants}, 1280x720 f=700 px B=0.063 m, thin guard {ranging_config(args.thin_guard_cm2).thin_guard_m2 * 1e4:g} cm^2")
    print(format_table(summary))
    print(format_width_table(widths))
    print(format_angle_table(angles))
    if args.per_distance:
        for r in rows:
            print(f"  {r['params']:8s} {r['variant']:6s} s{r['seed']} d={r['distance_m']:.2f} truth "
                  f"{r['truth_m']:.3f} sent {r['reported_m']} too_close {r['too_close']} q {r['quality']} "
                  f"err {fmt_pct(r['err'])}")


if __name__ == "__main__":
    main()
