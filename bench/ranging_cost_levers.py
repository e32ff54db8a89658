"""What the near check and the ranging cost with the flight file, and what cheaper fine passes would cost in readings.

The near check (the near pass) and the ranging (its fine pass and guards included) are timed frame by frame as
the daemon flies them (``uav-depth bench``'s ``near`` and ``range`` stages), with the ranging's share that is
OpenCV's SGBM timed apart: the fine pass's two matchers. Beside the flight file as it is, the levers that
would make the ranging cheaper by matching less, each a change of readings:

- ``fine WxH``: the fine pass's window (``FINE_MAX_COLS`` x ``FINE_MAX_ROWS``, today 160 x 96) smaller;
- ``no fine``: ``compute.fine_disparities: 0`` (the coarse reading only; the stated range shrinks with its
  precision floor).

Every lever runs on the same frames, interleaved frame by frame (a busy machine slows them alike), and each
reading is scored against the truth: the bench frames (branch 0.5-2 m), the leafy suite's 30 scenes, the near
sweep's plain / varied / leafy scenes from the minimum range out to the flight file's far working distance, and
the 17 real pairs (the reference: the same ranging on their ground truth). Per lever and set: readings that
differ from the flight file's, median |error|, frames read farther than the truth by more than 2 %, frames with
no measurement, and too close.

    .venv/bin/python bench/ranging_cost_levers.py --data DIR [--rounds 3] [--near-seeds 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import leafy_suite  # noqa: E402
import real_ranging  # noqa: E402
import scenebench  # noqa: E402

import uav_depth.core.disparity.fine as disparity_fine  # noqa: E402
import uav_depth.core.ranging.fine as ranging_fine  # noqa: E402
from uav_depth.cli import benchmark  # noqa: E402
from uav_depth.core.disparity import DisparityResult, flight_pipeline  # noqa: E402
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams  # noqa: E402
from uav_depth.core.params.flight import flight_params  # noqa: E402
from uav_depth.core.ranging import Ranger, RangingConfig, default_roi  # noqa: E402
from uav_depth.sim.scene import SceneConfig  # noqa: E402
from uav_depth.sim.sweep import VARIANTS  # noqa: E402

FARTHER_PCT = 2.0
#: name -> (fine window cols, rows, fine pass on)
LEVERS: dict[str, tuple[int, int, bool]] = {
    "flight": (ranging_fine.FINE_MAX_COLS, ranging_fine.FINE_MAX_ROWS, True),
    "fine 128x64": (128, 64, True),
    "fine 96x48": (96, 48, True),
    "no fine": (ranging_fine.FINE_MAX_COLS, ranging_fine.FINE_MAX_ROWS, False),
}


class Lever:
    """One lever's pipeline and ranging for one calibration and ROI."""

    def __init__(self, name: str, params: StereoParams, cal: Any, roi: tuple[int, int, int, int]):
        self.name = name
        self.cols, self.rows, fine = LEVERS[name]
        self.params = params if fine else params.replace(**{"compute.fine_disparities": 0})
        self.pipe = flight_pipeline(self.params)
        self.ranger = Ranger(RangingConfig(), cal, roi, self.params)

    def measure(self, left: np.ndarray, right: np.ndarray, sgbm_ms: list[float]) -> dict[str, Any]:
        ranging_fine.FINE_MAX_COLS, ranging_fine.FINE_MAX_ROWS = self.cols, self.rows
        sgbm_ms.clear()
        res = self.pipe.run(left, right)
        t0 = time.perf_counter()
        m = self.ranger.measure(res)
        rng = (time.perf_counter() - t0) * 1e3
        return {"m": m.distance_m, "too_close": m.too_close, "code": m.reason_code.name if m.reason_code else None,
                "near_ms": res.timings_ms.get("near", 0.0), "range_ms": rng, "fine_sgbm_ms": sum(sgbm_ms),
                "refined": m.refined}


def _timed_sgbm() -> list[float]:
    """Time the fine pass's two matchers (module-level functions the fine pass calls) into the returned list."""
    laps: list[float] = []
    for name in ("match_left", "match_right"):
        fn = getattr(disparity_fine, name)

        def timed(*a: Any, _fn: Callable = fn) -> Any:
            t = time.perf_counter()
            out = _fn(*a)
            laps.append((time.perf_counter() - t) * 1e3)
            return out
        setattr(disparity_fine, name, timed)
    return laps


def frames(args: argparse.Namespace) -> Iterator[tuple[str, str, np.ndarray, np.ndarray, float, Any, Any, Any]]:
    """(set, key, left, right, truth m, calibration, roi, params) of every frame scored."""
    flight = flight_params()
    for i, f in enumerate(benchmark.make_frames(12, 1280, 720, 0)):
        h, w = f.left.shape[:2]
        yield "bench", f"frame{i}", f.left, f.right, f.truth_m, f.scene.calibration, default_roi(w, h), flight
    fl = scenebench.param_sets(("flight",))["flight"]
    cfg = SceneConfig()
    for i in range(args.leafy_scenes):
        r = scenebench.render_cached(leafy_suite.scene(i))
        yield "leafy", f"scene{i}", r.left, r.right, r.truth_m, cfg.calibration, cfg.center_roi, fl
    far = scenebench.flight_max_range_m()
    dists = [round(d, 2) for d in np.arange(0.3, far + 1e-9, args.near_step_m)]
    for variant, make in VARIANTS.items():
        for seed in range(args.near_seeds):
            for d in dists:
                sc = make(d, seed)
                r = scenebench.render_cached(sc)
                yield "near", f"{variant}/s{seed}/{d:.2f}m", r.left, r.right, r.truth_m, sc.calibration, \
                    sc.center_roi, fl
    if args.data is not None:
        for name in real_ranging.SCENES:
            left, right, gt = real_ranging.load_scene(args.data, name)
            cal = real_ranging.calibration_for(gt)
            roi = default_roi(cal.width, cal.height)
            ref = Ranger(RangingConfig(), cal, roi, DEFAULT_PARAMS).measure(DisparityResult(gt, gt, None)).distance_m
            yield "real", name, left, right, float("nan") if ref is None else ref, cal, roi, fl


def summarize(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for s in sorted({r["set"] for r in rows}):
        base = {r["key"]: r for r in rows if r["set"] == s and r["lever"] == "flight"}
        for lever in LEVERS:
            rs = [r for r in rows if r["set"] == s and r["lever"] == lever]
            errs = [(r["m"] - r["truth"]) / r["truth"] * 100 for r in rs if r["m"] is not None and np.isfinite(r["truth"])]
            out.append({
                "set": s, "lever": lever, "frames": len(rs),
                "changed": sum(1 for r in rs if (r["m"], r["too_close"]) != (base[r["key"]]["m"],
                                                                            base[r["key"]]["too_close"])),
                "median_abs_err_pct": float(np.median(np.abs(errs))) if errs else None,
                "farther_2pct": sum(1 for e in errs if e > FARTHER_PCT),
                "worst_farther_pct": max(errs) if errs else None,
                "no_measurement": sum(1 for r in rs if r["m"] is None and not r["too_close"]),
                "too_close": sum(1 for r in rs if r["too_close"]),
                "near_ms": float(np.median([t for r in rs for t in r["near_ms"]])),
                "range_ms": float(np.median([t for r in rs for t in r["range_ms"]])),
                "fine_sgbm_ms": float(np.median([t for r in rs for t in r["fine_sgbm_ms"]])),
            })
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None, help="the 17 Middlebury 2006 pairs (left out: no real set)")
    ap.add_argument("--rounds", type=int, default=3, help="timed passes over each frame, per lever")
    ap.add_argument("--leafy-scenes", type=int, default=30)
    ap.add_argument("--near-seeds", type=int, default=2)
    ap.add_argument("--near-step-m", type=float, default=0.1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    sgbm_ms = _timed_sgbm()
    rows: list[dict[str, Any]] = []
    loads = [os.getloadavg()[0]]
    t_start = time.monotonic()
    for n, (sname, key, left, right, truth, cal, roi, params) in enumerate(frames(args)):
        levers = [Lever(name, params, cal, roi) for name in LEVERS]
        got: dict[str, dict[str, Any]] = {}
        for rnd in range(args.rounds):
            for lv in levers[rnd % len(levers):] + levers[:rnd % len(levers)]:     # rotate: none always first
                r = lv.measure(left, right, sgbm_ms)
                g = got.setdefault(lv.name, {"set": sname, "key": key, "lever": lv.name, "truth": truth,
                                             "m": r["m"], "too_close": r["too_close"], "code": r["code"],
                                             "near_ms": [], "range_ms": [], "fine_sgbm_ms": []})
                for k in ("near_ms", "range_ms", "fine_sgbm_ms"):
                    g[k].append(r[k])
        rows.extend(got.values())
        if n % 20 == 0:
            loads.append(os.getloadavg()[0])
            print(f"  {n + 1} frames, {time.monotonic() - t_start:.0f} s", file=sys.stderr, flush=True)
    loads.append(os.getloadavg()[0])
    summary = summarize(rows)
    print(benchmark.machine_line())
    print(f"load average {min(loads):.1f}-{max(loads):.1f}; {args.rounds} timed rounds a frame, levers interleaved")
    print(f"{'set':6s} {'lever':12s} {'frames':>6s} {'changed':>7s} {'med|err|':>8s} {'>2% far':>7s} "
          f"{'worst far':>9s} {'none':>5s} {'close':>5s} {'near ms':>7s} {'range ms':>8s} {'fine SGBM':>9s}")
    for r in summary:
        def pct(x: float | None) -> str:
            return "-" if x is None else f"{x:.2f}%"
        print(f"{r['set']:6s} {r['lever']:12s} {r['frames']:6d} {r['changed']:7d} {pct(r['median_abs_err_pct']):>8s} "
              f"{r['farther_2pct']:7d} {pct(r['worst_farther_pct']):>9s} {r['no_measurement']:5d} {r['too_close']:5d} "
              f"{r['near_ms']:7.2f} {r['range_ms']:8.2f} {r['fine_sgbm_ms']:9.2f}")
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "rows": rows, "loads": loads}, default=str))


if __name__ == "__main__":
    main()
