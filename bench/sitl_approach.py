"""SITL against a pymavlink vehicle: capture-to-autopilot latency and reading lag of the laptop config.

The loop test's vehicle (tests/cli/test_sitl_loop.py: HEARTBEAT, LOCAL_POSITION_NED and ATTITUDE
at the rate asked for) flies ``uav-depth sitl --config deploy/examples/sitl.yaml`` (the laptop
config as shipped, its flight parameters for 640x360) toward the tree: hovers at each of
``--stops`` (m from the branch surface) and flies between them at ``--speed``. Printed per run,
from what reached the vehicle: the DISTANCE_SENSOR rate and valid share; capture to arrival
(arrival minus ``time_boot_ms``, the frame's capture on the same CLOCK_MONOTONIC: one machine);
the reading lag while approaching (reading minus the geometry at arrival, m; ``--stops 2.4 0.6 2.4
0.6`` flies the approach twice); and, from the truth log,
the error against the ray-cast truth and the daemon's own stage times. ``--render full reads``
alternates runs of the two render modes, so both see the same load. Numbers, not assertions:

    nice -n 10 .venv/bin/python bench/sitl_approach.py --stops 4 1 --speed 2 --render full reads --runs 2
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import math
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


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, max(0, int(math.ceil(q * len(xs))) - 1))] if xs else float("nan")


def fly(render: str, stops: list[float], speed: float, hover_s: float, sets: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        example = REPO / "deploy/examples/sitl.yaml"
        config = yaml.safe_load(example.read_text())
        port = loop.free_udp_port()
        config["params_file"] = str((example.parent / config["params_file"]).resolve())
        config["mavlink"]["url"] = f"udpin:127.0.0.1:{port}"
        (tmp / "sitl.yaml").write_text(yaml.safe_dump(config))
        vehicle = loop.Vehicle(port, loop.Path(stops=tuple(stops), hover_s=hover_s, speed=speed))
        cmd = [sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config", str(tmp / "sitl.yaml"),
               "--tree-ned", *map(str, loop.TREE_NED), "--truth-log", str(tmp / "truth.csv"), "--render", render]
        for s in sets:
            cmd += ["--set", s]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
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
        msgs = [(t, m) for t, m in vehicle.readings if t0 <= t <= t1]
        rows = [r for r in csv.DictReader(open(tmp / "truth.csv")) if r["north_m"]]
    moving = [(a + t0, b + t0) for a, b, d0, d1 in vehicle.path.segments if d1 < d0]    # approaching
    lat, lat_moving, lag = [], [], []
    for t, m in msgs:
        if not loop.valid(m):
            continue
        lat.append(1000.0 * (t - m.time_boot_ms / 1000.0))
        if any(a + 0.3 <= t <= b for a, b in moving):    # at speed (0.3 s into the approach): every frame rendered
            lat_moving.append(lat[-1])
            lag.append(m.current_distance / 100.0 - (loop.TREE_NED[0] - vehicle.north(t)))
    errs = [abs(float(r["error_pct"])) for r in rows if r["error_pct"]]
    stage = [float(r["latency_ms"]) for r in rows if r["latency_ms"]]
    return {"render": render, "s": t1 - t0, "msgs": len(msgs), "valid": sum(loop.valid(m) for _, m in msgs),
            "lat": lat, "lat_moving": lat_moving, "lag": lag, "errs": errs, "stage": stage, "frames": len(rows),
            "tail": out[-1500:] if not msgs else ""}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stops", type=float, nargs="+", default=list(loop.STOPS), help="hover distances, m")
    ap.add_argument("--speed", type=float, default=loop.SPEED_MPS, help="m/s between the stops")
    ap.add_argument("--hover-s", type=float, default=loop.HOVER_S)
    ap.add_argument("--render", nargs="+", default=["reads"], choices=("reads", "full"))
    ap.add_argument("--runs", type=int, default=1, help="runs of each render mode, alternating")
    ap.add_argument("--set", action="append", default=[], help="KEY=VALUE for the daemon (uav-depth sitl --set)")
    args = ap.parse_args()
    print(f"deploy/examples/sitl.yaml, stops {args.stops} m, {args.speed} m/s between, hovers {args.hover_s} s")
    for i in range(args.runs):
        for render in args.render:
            r = fly(render, args.stops, args.speed, args.hover_s, args.set)
            with open("/proc/loadavg") as f:
                load = f.read().split()[0]
            print(f"--render {render} (run {i + 1}, load {load}): {r['msgs'] / r['s']:.1f} Hz DISTANCE_SENSOR, "
                  f"{r['valid']}/{r['msgs']} valid")
            if r["lat"]:
                print(f"  capture -> vehicle: median {statistics.median(r['lat']):.0f} ms, p95 {pct(r['lat'], 0.95):.0f} ms"
                      f" ({len(r['lat'])} readings); capture -> estimate (truth log) median "
                      f"{statistics.median(r['stage']):.0f} ms, p95 {pct(r['stage'], 0.95):.0f} ms")
            if r["lat_moving"]:
                print(f"  capture -> vehicle at speed (each frame rendered; a hover re-sends the cached pair): "
                      f"median {statistics.median(r['lat_moving']):.0f} ms, p95 {pct(r['lat_moving'], 0.95):.0f} ms")
            if r["lag"]:
                print(f"  reading lag at {args.speed:g} m/s: median {statistics.median(r['lag']):+.3f} m, "
                      f"p95 |lag| {pct([abs(x) for x in r['lag']], 0.95):.3f} m ({len(r['lag'])} readings)")
            if r["errs"]:
                print(f"  truth log: {r['frames']} frames, {len(r['errs'])} measured, |error| median "
                      f"{statistics.median(r['errs']):.2f} %, p95 {pct(r['errs'], 0.95):.2f} %")
            if r["tail"]:
                print("  no readings:\n" + r["tail"])


if __name__ == "__main__":
    main()
