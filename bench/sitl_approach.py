"""SITL: the loop test's vehicle flies deploy/examples/sitl.yaml toward the tree (any resolution).

Prints the DISTANCE_SENSOR rate and valid fraction on the wire and, from the truth log, the
per-frame error against the ray-cast truth and the latency. Numbers, not assertions:

    .venv/bin/python bench/sitl_approach.py [--width 1280 --height 720 --focal-px 700]   # default: the example's
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
# The vehicle of tests/cli/test_sitl_loop.py: one definition of the test autopilot.
_spec = importlib.util.spec_from_file_location("sitl_loop", REPO / "tests/cli/test_sitl_loop.py")
loop = importlib.util.module_from_spec(_spec)
sys.modules["sitl_loop"] = loop      # dataclasses look their module up there
_spec.loader.exec_module(loop)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=None, help="default: the example's")
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--focal-px", type=float, default=None)
    ap.add_argument("--fps", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        config = yaml.safe_load((REPO / "deploy/examples/sitl.yaml").read_text())
        port = loop.free_udp_port()
        config["source"]["fps"] = args.fps
        scene = config["source"]["scene"]
        for key in ("width", "height", "focal_px"):
            if getattr(args, key) is not None:
                scene[key] = getattr(args, key)
        scene.update(branch_distance_m=2.5, n_branches=0)
        config["mavlink"]["url"] = f"udpin:127.0.0.1:{port}"
        config["params_file"] = None
        config["logging"] = {"dir": None}
        (tmp / "sitl.yaml").write_text(yaml.safe_dump(config))
        vehicle = loop.Vehicle(port, loop.Path())
        proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config",
                                 str(tmp / "sitl.yaml"), "--tree-ned", *map(str, loop.TREE_NED),
                                 "--truth-log", str(tmp / "truth.csv")],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        vehicle.thread.start()
        deadline = time.monotonic() + 60
        while not any(loop.valid(m) for _, m in vehicle.readings) and time.monotonic() < deadline:
            time.sleep(0.05)
        t0 = vehicle.t_flight = time.monotonic()
        time.sleep(vehicle.path.duration)
        t1 = time.monotonic()
        vehicle.stop.set()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        status = [line for line in out.splitlines() if "status:" in line]
        msgs = [m for t, m in vehicle.readings if t0 <= t <= t1]
        rows = [r for r in csv.DictReader(open(tmp / "truth.csv")) if r["north_m"]]
    errs = sorted(abs(float(r["error_pct"])) for r in rows if r["error_pct"])
    lat = sorted(float(r["latency_ms"]) for r in rows if r["latency_ms"])
    print(f"{scene['width']}x{scene['height']} f={scene['focal_px']:g}px, approach 2.0 -> 0.6 m at {loop.SPEED_MPS} m/s "
          f"with {loop.HOVER_S} s hovers ({t1 - t0:.1f} s)")
    print(f"wire: {len(msgs) / (t1 - t0):.1f} Hz DISTANCE_SENSOR, {sum(map(loop.valid, msgs)) / max(1, len(msgs)):.0%} "
          "valid")
    if errs:
        print(f"truth log: {len(rows)} frames, {len(errs)} measured; |error| median "
              f"{statistics.median(errs):.2f} %, 95th pct {errs[int(0.95 * (len(errs) - 1))]:.2f} %, max {errs[-1]:.2f} %;"
              f" latency median {statistics.median(lat):.0f} ms")
    else:
        print("no measured frames:\n" + out[-2000:])
    if status:
        print("daemon:", status[-1].split("status: ", 1)[1])


if __name__ == "__main__":
    main()
