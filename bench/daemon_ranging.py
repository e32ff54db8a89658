"""The daemon measured as it flies: loop rate, per-stage times and branch-distance error.

Two parts, each for the manual baseline parameters and for deploy/params-flight.yaml:

1. ``loop``: the real Service in-process on a static synthetic 1280x720 scene (the
   source caches the rendered pair, so capture costs nothing and the figures are
   the stereo loop's), MAVLink to a real pymavlink endpoint on loopback. Prints
   stereo frames/s, per-stage medians and p90 (rectify, disparity, ranging, and
   capture-to-estimate latency), the DISTANCE_SENSOR rate the endpoint saw and the
   fraction sent as valid.
2. ``ranging``: the distance error against the ray-cast truth on synthetic scenes
   at 0.5, 1, 1.5 and 2 m (``--seeds`` scenes each, default imaging conditions, and
   the same with varied conditions: brightness, contrast, noise, blur, texture,
   radius), through the daemon's own pipeline and ranging. "Gross" errors (over
   10 %) are counted apart (none since the renderer lays its background tile at an
   irrational angle: a repeat inside the search range made SGBM match the wrong period
   with full confidence, and ranging saw a near object).

Run from the repository root:

    .venv/bin/python bench/daemon_ranging.py                 # both parts, about 4 minutes
    .venv/bin/python bench/daemon_ranging.py --part ranging --seeds 10
"""

from __future__ import annotations

import argparse
import logging
import socket
import threading
import time
from pathlib import Path

import numpy as np

from uav_depth.cli.benchmark import machine_line
from uav_depth.cli.sources import SOURCES
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.core.ranging import RangingConfig, Ranger
from uav_depth.core.disparity import DisparityPipeline
from uav_depth.daemon.link.vocabulary import mavutil
from uav_depth.core.params import DEFAULT_PARAMS, load_params
from uav_depth.sim.scene import Scene, SceneConfig, vary
from uav_depth.daemon.service import Service

ROOT = Path(__file__).resolve().parents[1]
DISTANCES = (0.5, 1.0, 1.5, 2.0)


def param_sets(names):
    sets = {"baseline": DEFAULT_PARAMS, "flight": load_params(ROOT / "deploy" / "params-flight.yaml")}
    return {n: sets[n] for n in names}


def pct(values, q):
    return float(np.percentile(values, q)) if len(values) else float("nan")


def bench_loop(params_name, params, seconds: float, tmp: Path) -> None:
    from uav_depth.core.params import save_params

    path = tmp / f"{params_name}.yaml"
    save_params(params, path)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    rx = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    arrivals = []
    stop_rx = threading.Event()

    def receive():
        while not stop_rx.is_set():
            m = rx.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.1)
            if m is not None:
                arrivals.append((time.monotonic(), m.signal_quality > 1))

    receiver = threading.Thread(target=receive, daemon=True)
    receiver.start()
    cfg = run_config_from_dict({
        "source": {"kind": "synthetic", "fps": 60, "scene": {"branch_distance_m": 1.0, "seed": 3}},
        "params_file": str(path), "mavlink": {"url": f"udpout:127.0.0.1:{port}", "rate_hz": 20},
        "service": {"status_interval_s": 3600}}, sources=SOURCES)
    svc = Service(cfg)
    stop = threading.Event()
    runner = threading.Thread(target=svc.run, args=(stop,), daemon=True)
    runner.start()
    while svc.stats.frames < 3 and runner.is_alive():
        time.sleep(0.05)
    t0, f0 = time.monotonic(), svc.stats.frames
    a0 = len(arrivals)
    time.sleep(seconds)
    t1, f1 = time.monotonic(), svc.stats.frames
    window = arrivals[a0:]
    stop.set()
    runner.join(30)
    stop_rx.set()
    receiver.join(2)
    rx.close()
    st = svc.stats.stages
    ds_rate = (len(window) - 1) / (window[-1][0] - window[0][0]) if len(window) > 1 else 0.0
    gaps = np.diff([t for t, _ in window]) * 1e3
    valid = sum(v for _, v in window) / max(1, len(window))
    print(f"  {params_name:<8} stereo {(f1 - f0) / (t1 - t0):5.1f} frames/s | " + " | ".join(
        f"{k} {pct(st[k], 50):6.1f} / {pct(st[k], 90):6.1f}" for k in ("rectify", "disparity", "ranging", "latency"))
        + f" ms (median / p90) | DISTANCE_SENSOR {ds_rate:5.2f} Hz, gap p50/p99/max {pct(gaps, 50):.0f}/"
        f"{pct(gaps, 99):.0f}/{gaps.max() if gaps.size else float('nan'):.0f} ms, {100 * valid:5.1f} % valid")


def bench_ranging(params_name, params, seeds: int) -> None:
    pipe = DisparityPipeline(params)
    base = SceneConfig()
    for label, varied in (("default scenes", False), ("varied scenes", True)):
        rows = []
        for dist in DISTANCES:
            errs, missing = [], 0
            for seed in range(seeds):
                rng = np.random.default_rng([seed, int(dist * 100)])
                cfg = (vary(base, rng, branch_distance_m=dist) if varied
                       else SceneConfig(branch_distance_m=dist, seed=seed))
                frame = Scene(cfg).render(rng=rng)
                truth = frame.nearest_branch_distance(cfg.center_roi)
                m = Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, params).measure(
                    pipe.run(frame.left, frame.right))
                if m.valid:
                    errs.append(100.0 * (m.distance_m - truth) / truth)
                else:
                    missing += 1
            a = np.abs(errs) if errs else np.array([np.nan])
            good = a[a <= 10.0]
            rows.append(f"{dist:.1f} m: median |err| {np.median(a):4.2f} %, max within 10 %: "
                        f"{good.max() if good.size else float('nan'):4.2f} %, gross (> 10 %) {int((a > 10).sum())}/{seeds}"
                        f", no measurement {missing}/{seeds}")
        print(f"  {params_name:<8} {label}:")
        for r in rows:
            print(f"    {r}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("loop", "ranging", "both"), default="both")
    ap.add_argument("--params", nargs="+", default=["baseline", "flight"], choices=("baseline", "flight"))
    ap.add_argument("--seconds", type=float, default=20.0, help="loop measurement window per parameter set")
    ap.add_argument("--seeds", type=int, default=5, help="scenes per distance")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    print(machine_line())
    sets = param_sets(args.params)
    if args.part in ("loop", "both"):
        import tempfile

        print(f"loop: synthetic 1280x720, branch at 1 m, {args.seconds:g} s per parameter set, DISTANCE_SENSOR at 20 Hz")
        with tempfile.TemporaryDirectory() as tmp:
            for name, params in sets.items():
                bench_loop(name, params, args.seconds, Path(tmp))
    if args.part in ("ranging", "both"):
        print(f"ranging: synthetic 1280x720 (f 700 px, B 0.063 m), {args.seeds} scenes per distance, "
              "error of the daemon's distance against the ray-cast nearest branch surface")
        for name, params in sets.items():
            bench_ranging(name, params, args.seeds)


if __name__ == "__main__":
    main()
