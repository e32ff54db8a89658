"""Leafy suite: synthetic radiata-pine scenes with twigs, needles and foliage in front of the target, 0.3-2 m.

``--scenes`` scenes (default 30), scene i drawn by ``vary(SceneConfig(),
default_rng([i, 202]), leafy=True)`` with the target branch at 0.45-2 m and the
foliage layer within 30 % in front of it, so the truth (the nearest significant
object in the ranging region: at least 3 mm thick and 2 cm^2 visible, so a twig or
the branch, never a needle alone; sim/truth.py) lies between 0.3 and 2 m. Each scene
is measured as the daemon does (pipeline, Ranger, distance_report) with the manual
baseline and deploy/params-flight.yaml.

Printed per parameter set: median |error|, worst error (signed), frames reported
farther than the truth by more than 5 %, frames nearer by more than 5 % (e.g. a
needle cloud read as the obstacle: safe, but not the truth), and frames without a
measurement. ``--per-scene`` adds one line per scene; where nothing was sent it ends with
the ranging's reason (a reading the quality floor refused names the distance it would
have sent).

    .venv/bin/python bench/leafy_suite.py                 # 30 scenes, both parameter files
    .venv/bin/python bench/leafy_suite.py --scenes 60 --params flight --json
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from scenebench import (PARAM_SET_NAMES, Measurer, add_ranging_args, fmt_pct, param_sets, ranging_config, rel_err,
                        render_cached)

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.ranging import RangingConfig
from uav_depth.sim.scene import SceneConfig, vary

FARTHER_TOL = 0.05


def scene(i: int) -> SceneConfig:
    """Leafy scene ``i`` of the suite (a fixed function of ``i``)."""
    rng = np.random.default_rng([i, 202])
    d = float(rng.uniform(0.45, 2.0))
    return vary(SceneConfig(), rng, leafy=True, branch_distance_m=d,
                foliage_front_rel=float(rng.uniform(0.1, 0.3)))


def suite(n_scenes: int = 30, params_names=("baseline", "flight"), cache: bool = True,
          ranging: RangingConfig | None = None) -> list[dict[str, Any]]:
    """One row per (parameter set, scene)."""
    measurers = {name: Measurer(p, SceneConfig(), ranging) for name, p in param_sets(params_names).items()}
    rows = []
    for i in range(n_scenes):
        cfg = scene(i)
        frame = render_cached(cfg, cache)
        for name, meas in measurers.items():
            out = meas.measure(frame.left, frame.right)
            err = rel_err(out["reported_m"], frame.truth_m)
            exact = meas.measure_exact(frame.disparity)
            rows.append({"params": name, "scene": i, "target_m": frame.target_m, "truth_m": frame.truth_m,
                         "nearest_any_m": frame.nearest_any_m, **out, "err": err, "exact_m": exact,
                         "exact_err": rel_err(exact, frame.truth_m),
                         "farther": bool(err is not None and err > FARTHER_TOL),
                         "nearer": bool(err is not None and err < -FARTHER_TOL)})
    return rows


def summarize(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for name in dict.fromkeys(r["params"] for r in rows):
        rs = [r for r in rows if r["params"] == name]
        errs = [r["err"] for r in rs if r["err"] is not None]
        ex = [r["exact_err"] for r in rs if r["exact_err"] is not None]
        out.append({"params": name, "scenes": len(rs),
                    "exact_median_abs_err": float(np.median(np.abs(ex))) if ex else None,
                    "exact_worst_err": max(ex, key=abs) if ex else None,
                    "exact_farther_5pct": sum(e > FARTHER_TOL for e in ex),
                    "median_abs_err": float(np.median(np.abs(errs))) if errs else None,
                    "worst_err": max(errs, key=abs) if errs else None,
                    "farther_5pct": sum(r["farther"] for r in rs), "nearer_5pct": sum(r["nearer"] for r in rs),
                    "no_measurement": sum(r["reported_m"] is None for r in rs),
                    "truth_range_m": [min(r["truth_m"] for r in rs), max(r["truth_m"] for r in rs)]})
    return out


def format_table(summary: list[dict[str, Any]]) -> str:
    head = (f"{'params':9s} {'scenes':>6s} {'median|e|':>9s} {'worst':>9s} {'farther>5%':>10s} {'nearer>5%':>9s} "
            f"{'no meas':>7s} | {'exact: median|e|':>16s} {'worst':>8s} {'farther>5%':>10s}")
    lines = [head, "-" * len(head)]
    for s in summary:
        lines.append(f"{s['params']:9s} {s['scenes']:6d} {fmt_pct(s['median_abs_err']):>9s} "
                     f"{fmt_pct(s['worst_err']):>9s} {s['farther_5pct']:10d} {s['nearer_5pct']:9d} "
                     f"{s['no_measurement']:7d} | {fmt_pct(s['exact_median_abs_err']):>16s} "
                     f"{fmt_pct(s['exact_worst_err']):>8s} {s['exact_farther_5pct']:10d}")
    lines.append("exact: the same ranging on the exact ray-cast disparity (no matcher): the ranging's own error")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--params", nargs="+", default=["baseline", "flight"], choices=PARAM_SET_NAMES)
    ap.add_argument("--no-cache", action="store_true")
    ap.add_argument("--json", action="store_true", help="print rows and summary as JSON instead of the table")
    ap.add_argument("--per-scene", action="store_true", help="also print one line per scene")
    add_ranging_args(ap)
    args = ap.parse_args(argv)
    rows = suite(args.scenes, args.params, cache=not args.no_cache,
                 ranging=ranging_config(args.thin_guard_cm2))
    summary = summarize(rows)
    if args.json:
        print(json.dumps({"summary": summary, "rows": rows}, indent=1))
        return
    print(machine_line())
    lo, hi = summary[0]["truth_range_m"]
    print(f"leafy suite: {args.scenes} scenes 1280x720, truth {lo:.2f}..{hi:.2f} m (nearest significant object), "
          f"thin guard {ranging_config(args.thin_guard_cm2).thin_guard_m2 * 1e4:g} cm^2")
    print(format_table(summary))
    if args.per_scene:
        for r in rows:
            print(f"  {r['params']:8s} scene {r['scene']:2d} target {r['target_m']:.3f} truth {r['truth_m']:.3f} "
                  f"any {r['nearest_any_m']:.3f} sent {r['reported_m']} q {r['quality']} err {fmt_pct(r['err'])} "
                  f"exact {fmt_pct(r['exact_err'])}" + (f" ({r['reason']})" if r["reported_m"] is None else ""))


if __name__ == "__main__":
    main()
