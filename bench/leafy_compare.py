"""Two parameter files, side by side, on leafy-generator scenes A..B-1, as the daemon flies: is the difference
larger than the scenes' own spread?

The leafy suite's 30 scenes are few for a comparison: a scene read or missed moves the mean safety-weighted
branch error (``tuning.metrics.safe_branch_error``: a miss costs 100 %, a reading more than 2 % farther than
the truth 100 % + its error) by 3.3 points. This prints, per file, the mean safety-weighted and plain errors,
the frames without a measurement, read farther than the truth by more than 2 % and 5 %, and nearer by more
than 5 %, and the paired difference (second file minus first) with a bootstrap 95 % interval (10 000
resamples of the scenes, seeded). Scenes 30..129 are the default: the suite uses 0..29, the tuning benchmarks
train on 1000 and up, so none is trained on or was used to choose anything.

    .venv/bin/python bench/leafy_compare.py deploy/params-flight.yaml tuned.yaml
    .venv/bin/python bench/leafy_compare.py deploy/params-flight.yaml tuned.yaml --first 0 --last 30 --json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from leafy_suite import scene
from scenebench import Measurer, rel_err, render_cached

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.params import load_params
from uav_depth.sim.scene import SceneConfig
from uav_depth.tuning.metrics import FARTHER_TOL_PCT, branch_error, safe_branch_error

BOOTSTRAP = 10_000


def compare(files: list[Path], first: int, last: int) -> list[dict]:
    """One row per scene: its truth and, per file, the reported distance and its errors."""
    meas = {str(f): Measurer(load_params(f), SceneConfig()) for f in files}
    rows = []
    for i in range(first, last):
        fr = render_cached(scene(i))
        row = {"scene": i, "truth_m": fr.truth_m}
        for name, m in meas.items():
            out = m.measure(fr.left, fr.right)
            row[name] = {"reported_m": out["reported_m"], "too_close": out["too_close"],
                         "err": rel_err(out["reported_m"], fr.truth_m),
                         "safe": safe_branch_error(out["reported_m"], fr.truth_m),
                         "plain": branch_error(out["reported_m"], fr.truth_m)}
        rows.append(row)
    return rows


def summary(rows: list[dict], name: str) -> dict:
    errs = [r[name]["err"] for r in rows if r[name]["err"] is not None]
    return {"file": name, "scenes": len(rows), "mean_safe_pct": float(np.mean([r[name]["safe"] for r in rows])),
            "mean_plain_pct": float(np.mean([r[name]["plain"] for r in rows])),
            "no_measurement": sum(r[name]["reported_m"] is None for r in rows),
            "farther_2pct": sum(e > FARTHER_TOL_PCT / 100 for e in errs), "farther_5pct": sum(e > 0.05 for e in errs),
            "nearer_5pct": sum(e < -0.05 for e in errs),
            "median_abs_err": float(np.median(np.abs(errs))) if errs else None}


def paired(rows: list[dict], a: str, b: str, seed: int = 0) -> dict:
    d = np.array([r[b]["safe"] - r[a]["safe"] for r in rows])
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), (BOOTSTRAP, len(d)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return {"mean_diff_pct": float(d.mean()), "ci95": [float(lo), float(hi)], "better": int((d < -1).sum()),
            "worse": int((d > 1).sum()), "same": int((abs(d) <= 1).sum())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first_file", type=Path)
    ap.add_argument("second_file", type=Path)
    ap.add_argument("--first", type=int, default=30, help="first scene index (default 30)")
    ap.add_argument("--last", type=int, default=130, help="one past the last scene index (default 130)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    files = [args.first_file, args.second_file]
    rows = compare(files, args.first, args.last)
    sums = [summary(rows, str(f)) for f in files]
    pair = paired(rows, str(files[0]), str(files[1]))
    if args.json:
        print(json.dumps({"summary": sums, "paired": pair, "rows": rows}, indent=1))
        return 0
    print(machine_line())
    print(f"leafy-generator scenes {args.first}..{args.last - 1}, as the daemon flies:")
    print(f"{'file':40s} {'safety-wt':>9s} {'plain':>7s} {'no meas':>7s} {'far>2%':>6s} {'far>5%':>6s} "
          f"{'near>5%':>7s} {'median|e|':>9s}")
    for s in sums:
        med = "-" if s["median_abs_err"] is None else f"{100 * s['median_abs_err']:.2f}%"
        print(f"{s['file'][-40:]:40s} {s['mean_safe_pct']:8.1f}% {s['mean_plain_pct']:6.1f}% {s['no_measurement']:7d} "
              f"{s['farther_2pct']:6d} {s['farther_5pct']:6d} {s['nearer_5pct']:7d} {med:>9s}")
    print(f"second minus first, safety-weighted: {pair['mean_diff_pct']:+.1f} points, bootstrap 95 % interval "
          f"{pair['ci95'][0]:+.1f} .. {pair['ci95'][1]:+.1f}; better on {pair['better']}, worse on {pair['worse']}, "
          f"within 1 point on {pair['same']} scenes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
