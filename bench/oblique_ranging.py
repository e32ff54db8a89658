"""Oblique branches: the laptop SITL scene seen at braking and turning attitudes, every frame judged on the wire.

The scene ``uav-depth sitl`` renders (deploy/examples/sitl.yaml: 640x360, its flight parameters), the
rig ``--distances`` m short of the branch and pitched/yawed by each of ``--pitch`` x ``--yaw`` degrees
(a copter braking pitches up about 7 degrees; the walk-through's approach also yawed about 7), over
``--seeds`` scenes, through the daemon's own pipeline and ranging. The truth is the nearest point of
the nearest significant object in the ranging region (sim/truth.py, as the other scene benches): for a
branch seen obliquely, its near end, often a few pixels at the region's edge. Printed: frames, frames
sent as a distance, median |error|, worst farther, frames farther than the truth by more than 2 % and
5 %, how many the same ranging on the exact disparity reads farther than 2 % (the rules' own share of
the error), and how many readings miss the truth by more than twice the sigma they are sent with;
``-v`` lists the farther ones.
Numbers, not assertions:

    .venv/bin/python bench/oblique_ranging.py [-v]      # 3 seeds x 8 distances x 12 attitudes, ~20 s
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
from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging import Ranger, resolve_roi
from uav_depth.daemon.stage import build_stage
from uav_depth.sim.scene import Pose, Scene
from uav_depth.sim.sitl import rot_x, rot_y

REPO = Path(__file__).resolve().parents[1]
SCENE_DEPTH_M = 3.5      # the branch stands this far in front of the scene's origin


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(REPO / "deploy/examples/sitl.yaml"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--distances", type=float, nargs="+", default=[1.2, 1.5, 1.8, 2.1, 2.4, 2.7, 3.0, 3.3])
    ap.add_argument("--pitch", type=float, nargs="+", default=[-7.0, 0.0, 4.0, 7.0])
    ap.add_argument("--yaw", type=float, nargs="+", default=[-7.0, 0.0, 7.0])
    ap.add_argument("-v", action="store_true", help="list the frames read farther than 2 %")
    args = ap.parse_args()
    config = load_run_config(args.config, sources=SOURCES)
    base = config.source.scene
    calib = base.calibration
    roi = resolve_roi(config.ranging.roi, calib.width, calib.height)
    stage = build_stage(load_params(config.params_file), str(config.params_file), config.ranging, calib, roi)
    errs, farther, n, exact_errs, outside = [], [], 0, [], 0
    # The ranging's own error: the same rules on the exact disparity (no matcher), every reading compared.
    exact = Ranger(replace(config.ranging, max_sigma_m=100.0, min_quality=0), calib, roi, stage.ranger.params)
    for seed in args.seeds:
        scene = Scene(replace(base, seed=seed, branch_distance_m=SCENE_DEPTH_M))
        for d in args.distances:
            for p in args.pitch:
                for y in args.yaw:
                    pose = Pose(rot_x(math.radians(p)) @ rot_y(math.radians(y)),
                                np.array([0.0, 0.0, SCENE_DEPTH_M - d]))
                    frame = scene.render(pose, np.random.default_rng([seed, int(d * 100), int(p) + 50, int(y) + 50]))
                    truth = frame.truth(roi).significant_m
                    m = stage.ranger.measure(stage.pipeline.run(frame.left, frame.right))
                    ex = np.where(frame.disparity > 0, frame.disparity, np.nan).astype(np.float32)
                    z_exact = exact.measure(DisparityResult(ex, ex, None)).distance_m
                    if z_exact is not None:
                        exact_errs.append((z_exact - truth) / truth)
                    n += 1
                    if m.distance_m is None:
                        continue
                    e = (m.distance_m - truth) / truth
                    errs.append(e)
                    outside += abs(m.distance_m - truth) > 2.0 * m.sigma_m
                    if e > 0.02:
                        farther.append((seed, d, p, y, truth, m.distance_m, e, z_exact))
    for seed, d, p, y, truth, z, e, zx in farther if args.v else []:
        xs = "-" if zx is None else f"{zx:.3f} ({100 * (zx - truth) / truth:+.1f} %)"
        print(f"  farther: seed {seed} {d:.1f} m pitch {p:+.0f} yaw {y:+.0f}: truth {truth:.3f} read {z:.3f} "
              f"({100 * e:+.1f} %), exact disparity reads {xs}")
    print(f"{base.width}x{base.height}, {config.params_file.name}: {n} frames, {len(errs)} sent; median |error| "
          f"{100 * statistics.median(abs(e) for e in errs):.2f} %, worst farther {100 * max(errs):+.2f} %, "
          f"farther > 2 %: {len(farther)}, > 5 %: {sum(e > 0.05 for e in errs)}; the same ranging on the exact "
          f"disparity: farther > 2 % {sum(e > 0.02 for e in exact_errs)} of {len(exact_errs)}; "
          f"|error| > 2 sigma (the covariance sent): {outside} of {len(errs)}")


if __name__ == "__main__":
    main()
