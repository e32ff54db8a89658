"""Where a SITL frame's time goes: render, rectify, stereo, ranging, with the laptop config (in process).

The config of ``uav-depth sitl`` on a laptop (deploy/examples/sitl.yaml, its flight parameters for
640x360) on the scene it renders, the rig hovering 2 m (``--distance``) from the branch with a small attitude
jitter every frame (as an autopilot's pose has, so nothing is cached between frames). Full renders and
renders of only what the flight pipeline reads (``--render reads``, the default of ``uav-depth sitl``)
alternate frame by frame, so both see the same load. Numbers, not assertions:

    nice -n 10 .venv/bin/python bench/sitl_latency.py [--frames 40] [--distance 3]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import numpy as np

from uav_depth.cli.sources import SOURCES
from uav_depth.core.params import load_params
from uav_depth.core.rectify import Rectifier
from uav_depth.daemon.config import load_run_config
from uav_depth.core.ranging import resolve_roi
from uav_depth.daemon.stage import build_stage
from uav_depth.sim.scene import Pose, Scene
from uav_depth.sim.sitl import rot_x, rot_y
from uav_depth.sim.source import pipeline_reads

REPO = Path(__file__).resolve().parents[1]


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(math.ceil(q * len(xs))) - 1)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(REPO / "deploy/examples/sitl.yaml"))
    ap.add_argument("--frames", type=int, default=40, help="frames per mode")
    ap.add_argument("--distance", type=float, default=2.0, help="rig to branch surface, m")
    args = ap.parse_args()
    config = load_run_config(args.config, sources=SOURCES)
    sc = config.source.scene
    scene = Scene(sc)
    calib = sc.calibration
    params = load_params(config.params_file)
    roi = resolve_roi(config.ranging.roi, calib.width, calib.height)
    stage = build_stage(params, str(config.params_file), config.ranging, calib, roi)
    rect = Rectifier(calib)
    reads = pipeline_reads(params, calib.width, calib.height)
    win = (min(reads[0], roi[0]), min(reads[1], roi[1]), max(reads[2], roi[2]), max(reads[3], roi[3]))
    share = (win[2] - win[0]) * (win[3] - win[1]) / (calib.width * calib.height)
    print(f"{sc.width}x{sc.height}, {config.params_file}; the pipeline reads {list(win)} ({share:.0%} of the frame)")
    rng = np.random.default_rng(0)
    times: dict[str, dict[str, list[float]]] = {m: {} for m in ("full", "reads")}
    dist: dict[str, list[float]] = {"full": [], "reads": []}
    for i in range(args.frames):
        for mode in (("full", "reads") if i % 2 == 0 else ("reads", "full")):
            jitter = rng.normal(0, 0.01, 3)
            pose = Pose(rot_x(jitter[0]) @ rot_y(jitter[1]),
                        np.array([jitter[2], 0.0, sc.branch_distance_m - args.distance]))
            t0 = time.perf_counter()
            frame = scene.render(pose, np.random.default_rng([sc.seed, i]), None if mode == "full" else win)
            t1 = time.perf_counter()
            left, right = rect(frame.left, frame.right)
            t2 = time.perf_counter()
            result = stage.pipeline.run(left, right)
            t3 = time.perf_counter()
            m = stage.ranger.measure(result)
            t4 = time.perf_counter()
            for k, v in (("render", t1 - t0), ("rectify", t2 - t1), ("stereo", t3 - t2), ("ranging", t4 - t3),
                         ("total", t4 - t0)):
                times[mode].setdefault(k, []).append(1000 * v)
            if m.valid:
                dist[mode].append(m.distance_m - frame.nearest_branch_distance(roi))
    print(f"{args.frames} frames per mode, interleaved; ms median / p95")
    for k in times["full"]:
        f, r = times["full"][k], times["reads"][k]
        print(f"  {k:8s} full {statistics.median(f):6.1f} / {pct(f, 0.95):6.1f}   reads {statistics.median(r):6.1f} / "
              f"{pct(r, 0.95):6.1f}   ratio {statistics.median(r) / max(1e-9, statistics.median(f)):.2f}")
    for mode, errs in dist.items():
        if errs:
            print(f"  {mode}: {len(errs)}/{args.frames} measured, error median {1000 * statistics.median(errs):+.0f} mm")
        else:
            print(f"  {mode}: nothing measured")


if __name__ == "__main__":
    main()
