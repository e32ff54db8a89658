"""Hovering at known distances: the laptop config's error against the truth, and its reported sigma.

The scene ``uav-depth sitl`` renders (deploy/examples/sitl.yaml: 640x360, its flight parameters), the
rig hovering ``--distances`` m from the branch surface with a small attitude and position jitter per
frame (an autopilot's hover), fresh sensor noise per frame, over ``--seeds`` scenes; each frame goes
through the daemon's own pipeline, ranging and DISTANCE_SENSOR encoding
(:func:`uav_depth.daemon.link.contract.distance_report`). Printed per distance: frames sent as a
distance, the error (median, p95 of |error|), the share within 2 % and the share with |error| within
2 sigma of the covariance on the wire, and the disparity error (input px) that the sigma model has to
cover. Numbers, not assertions:

    nice -n 10 .venv/bin/python bench/sitl_hover.py [--distances 1 2 3 4 5] [--seeds 3] [--frames 20]
"""

from __future__ import annotations

import argparse
import math
import statistics
from dataclasses import replace
from pathlib import Path

import numpy as np

from uav_depth.cli.sources import SOURCES
from uav_depth.core.params import load_params
from uav_depth.daemon.config import load_run_config
from uav_depth.daemon.link.contract import distance_report
from uav_depth.core.ranging import resolve_roi
from uav_depth.daemon.estimate import Estimate
from uav_depth.daemon.stage import build_stage
from uav_depth.sim.scene import Pose, Scene
from uav_depth.sim.sitl import rot_x, rot_y

REPO = Path(__file__).resolve().parents[1]


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, max(0, int(math.ceil(q * len(xs))) - 1))] if xs else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(REPO / "deploy/examples/sitl.yaml"))
    ap.add_argument("--distances", type=float, nargs="+", default=[1.0, 2.0, 3.0, 4.0, 5.0])
    ap.add_argument("--seeds", type=int, default=3, help="scenes (seed 1 is the example's)")
    ap.add_argument("--frames", type=int, default=20, help="frames per distance and scene")
    ap.add_argument("--set", action="append", default=[], help="ranging.KEY=VALUE for the ranging config")
    ap.add_argument("--jitter", type=float, default=1.0, help="scale of the hover jitter (0: level and still)")
    args = ap.parse_args()
    config = load_run_config(args.config, sources=SOURCES)
    ranging = config.ranging
    for s in args.set:
        k, v = s.split("=", 1)
        ranging = replace(ranging, **{k.removeprefix("ranging."): type(getattr(ranging, k.removeprefix("ranging.")))(v)})
    base = config.source.scene
    params = load_params(config.params_file)
    calib = base.calibration
    roi = resolve_roi(ranging.roi, calib.width, calib.height)
    stage = build_stage(params, str(config.params_file), ranging, calib, roi)
    lim = stage.ranger.limits
    print(f"{base.width}x{base.height} f {base.focal_px:g} px B {base.baseline_m:g} m, {config.params_file}; "
          f"range {lim.min_distance_m:.2f}..{lim.max_distance_m:.2f} m, min_quality {ranging.min_quality}; "
          f"{args.seeds} scenes x {args.frames} frames per distance")
    rng = np.random.default_rng(0)
    fb = calib.focal_px * calib.baseline_m
    for d in args.distances:
        errs, within2s, within2p, sent, dd, sig, frames = [], 0, 0, 0, [], [], 0
        reasons: dict[str, int] = {}
        for seed in range(1, args.seeds + 1):
            cfg = replace(base, seed=seed, branch_distance_m=d)
            scene = Scene(cfg)
            for i in range(args.frames):
                j = rng.normal(0, [0.01, 0.01, 0.02]) * args.jitter
                pose = Pose(rot_x(j[0]) @ rot_y(j[1]), np.array([j[2], 0.0, 0.0]))
                frame = scene.render(pose, np.random.default_rng([seed, i, int(d * 100)]))
                truth = frame.nearest_branch_distance(roi)
                m = stage.ranger.measure(stage.pipeline.run(frame.left, frame.right))
                est = Estimate(m, lim, 0.0, 0.0, i, stage.hash, truth, {}, too_close=m.too_close)
                r = distance_report(est, lim, 0.0, 1.0)
                frames += 1
                if not r.valid:
                    why = (m.reason or r.condition).split(" (")[0][:60]
                    reasons[why] = reasons.get(why, 0) + 1
                    continue
                sent += 1
                z = r.current_distance / 100.0
                e = z - truth
                errs.append(e)
                sigma = math.sqrt(r.covariance) / 100.0 if r.covariance < 255 else math.inf
                sig.append(sigma)
                within2s += abs(e) <= 2 * sigma + 0.01       # + 1 cm: the wire's whole centimetres
                within2p += abs(e) <= 0.02 * truth
                dd.append(fb / m.distance_m - fb / truth)
        line = f"  {d:g} m: {sent}/{frames} sent"
        if errs:
            line += (f"; error median {100 * statistics.median(errs):+.1f} cm, p95 |error| "
                     f"{100 * pct([abs(e) for e in errs], 0.95):.1f} cm; within 2 % {within2p / sent:.0%}, "
                     f"|error| <= 2 sigma {within2s / sent:.0%} (sigma median {100 * statistics.median(sig):.1f} cm); "
                     f"disparity error median {statistics.median(dd):+.3f} px, p95 |.| {pct([abs(x) for x in dd], 0.95):.3f} px")
        if reasons:
            line += "; not sent: " + ", ".join(f"{n} {why}" for why, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
        print(line, flush=True)


if __name__ == "__main__":
    main()
