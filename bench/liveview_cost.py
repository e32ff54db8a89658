"""What the live view costs the flight loop: per-frame stereo time with the view off, on but
unwatched, and watched (a viewer polling the picture and the figures as the page does), interleaved.

    python bench/liveview_cost.py [--rounds 3] [--seconds 6] [--width 640]

Prints, per mode, the median and p99 of the stereo stage's per-frame time (rectify + disparity +
ranging, ms) and of the frame latency (capture -> estimate, ms), over all rounds, plus the
pictures the view encoded. The viewer is a separate process (a browser would be on the laptop).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time

import numpy as np

from uav_depth.cli.sources import SOURCES
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.daemon.service import Service

VIEWER = """
import sys, time, urllib.request
url, until = sys.argv[1], time.monotonic() + float(sys.argv[2])
while time.monotonic() < until:
    for path in ("frame.jpg", "state.json"):
        try:
            urllib.request.urlopen(url + path, timeout=2).read()
        except OSError:
            pass
    time.sleep(0.2)
"""


def one_round(mode: str, seconds: float, width: int, params_file: str, port: int) -> tuple[list, list, int]:
    height = width * 9 // 16
    cfg = run_config_from_dict({
        "source": {"kind": "synthetic", "fps": 10,
                   "scene": {"width": width, "height": height, "focal_px": width * 350.0 / 640,
                             "branch_distance_m": 1.5, "seed": 1}},
        "params_file": params_file, "ranging": {"max_age_ms": 450},
        "mavlink": {"url": "udpout:127.0.0.1:9"},
        "liveview": {"enabled": mode != "off", "port": port},
    }, sources=SOURCES)
    svc = Service(cfg)
    stop = threading.Event()
    t = threading.Thread(target=svc.run, args=(stop,), daemon=True)
    t.start()
    while svc.stats.frames < 3:
        time.sleep(0.05)
    viewer = None
    if mode == "watched":
        viewer = subprocess.Popen([sys.executable, "-c", VIEWER, f"http://127.0.0.1:{port}/", str(seconds)])
    n0 = svc.stats.frames
    time.sleep(seconds)
    n = svc.stats.frames - n0
    stages = {k: list(v)[-n:] for k, v in svc.stats.stages.items()}
    encoded = svc.liveview.encoded if svc.liveview is not None else 0
    stop.set()
    t.join(10)
    if viewer is not None:
        viewer.wait(10)
    work = [a + b + c for a, b, c in zip(stages["rectify"], stages["disparity"], stages["ranging"])]
    return work, stages["latency"], encoded


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--params", default=None, help="parameter file (default: manual defaults, 64 disparities)")
    args = ap.parse_args()
    params = args.params
    if params is None:
        params = "/tmp/liveview_cost_params.yaml"
        save_params(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64}), params)
    modes = ("off", "unwatched", "watched")
    work = {m: [] for m in modes}
    lat = {m: [] for m in modes}
    enc = {m: 0 for m in modes}
    for r in range(args.rounds):
        for i, mode in enumerate(modes if r % 2 == 0 else modes[::-1]):   # interleaved, order alternating
            w, lt, e = one_round(mode, args.seconds, args.width, params, 18700 + 10 * r + i)
            work[mode] += w
            lat[mode] += lt
            enc[mode] += e
            print(f"round {r + 1} {mode:9s}: {len(w)} frames, stereo median {np.median(w):.1f} ms", flush=True)
    print(f"\n{args.width}x{args.width * 9 // 16}, {args.rounds} rounds x {args.seconds:g} s per mode")
    print("mode       frames  stereo ms median  p99   latency ms median  p99   pictures encoded")
    for m in modes:
        w, lt = np.array(work[m]), np.array(lat[m])
        print(f"{m:9s}  {len(w):6d}  {np.median(w):16.1f}  {np.percentile(w, 99):5.1f}  "
              f"{np.median(lt):17.1f}  {np.percentile(lt, 99):5.1f}   {enc[m]}")


if __name__ == "__main__":
    main()
