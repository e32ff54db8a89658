"""ArduCopter SITL + uav-depth sitl: approach the branch with avoidance on, hover at known distances.

Numbers, not assertions. Needs the SITL binary (UAV_DEPTH_ARDUCOPTER=/path/to/arducopter; docs/sitl.md):

    UAV_DEPTH_ARDUCOPTER=.../build/sitl/bin/arducopter .venv/bin/python bench/sitl_ardupilot.py \
        [--sensors prx rf] [--modes Guided Loiter] [--speeds 0.5 1 2] [--hover 2 3 4 5] [--set AVOID_MARGIN=1.5]

For each sensor set-up (prx: PRX1_TYPE=2 fed by the daemon's DISTANCE_SENSOR; rf: RNGFND1_TYPE=10 with
PRX1_TYPE=4) one SITL boots, takes the parameters in the autopilot's order (type, reboot, orientation and
limits), the daemon starts (deploy/examples/sitl.yaml, the branch at N 7.5 m, 3 m up), the copter arms,
takes off to 3 m and flies north at the branch from 5.5 m away, at each speed in each mode (Guided
velocity, Loiter full stick at LOIT_SPEED), back to the start in between. Printed per flight: the
closest approach of the camera to the branch surface (from LOCAL_POSITION_NED; negative = through it),
whether it stopped, and the autopilot's own reading minus the geometry at the same instant while at
speed (the reading lag, m). Then it hovers 2, 3, 4 and 5 m from the branch: the daemon's error against the
ray-cast truth (its truth log) and how often |error| <= 2 sigma of the covariance it sent; and the
daemon's capture-to-estimate latency (truth log), the part of capture-to-autopilot it controls.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# One definition of the SITL harness: the end-to-end test's.
_spec = importlib.util.spec_from_file_location("sitl_ardupilot", REPO / "tests/cli/test_sitl_ardupilot.py")
h = importlib.util.module_from_spec(_spec)
sys.modules["sitl_ardupilot"] = h      # dataclasses look their module up there
_spec.loader.exec_module(h)


def truth_rows(path: Path, t_from: float, t_to: float) -> list[dict]:
    """Truth-log rows captured in [t_from, t_to] (monotonic s: one clock for every process here)."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return [r for r in rows if r["monotonic_s"] and t_from <= float(r["monotonic_s"]) <= t_to]


def hover(sitl, truth: Path, distance_m: float, hold_s: float = 12.0) -> dict:
    sitl.goto(h.TREE_N - distance_m)
    t0 = time.monotonic()
    while time.monotonic() - t0 < hold_s:
        sitl.target_position(h.TREE_N - distance_m, 0.0, -h.ALT_M)
        time.sleep(0.2)
    rows = truth_rows(truth, t0, time.monotonic())
    measured = [r for r in rows if r["measured_m"] and r["truth_m"]]
    errs = [float(r["measured_m"]) - float(r["truth_m"]) for r in measured]
    sig = [float(r["sigma_m"]) if r["sigma_m"] else math.inf for r in measured]
    within = sum(abs(e) <= 2 * s for e, s in zip(errs, sig))
    return {"d": distance_m, "frames": len(rows), "measured": len(measured),
            "err_m": statistics.median(errs) if errs else None,
            "err_pct": 100 * statistics.median(errs) / distance_m if errs else None,
            "sigma_m": statistics.median(sig) if sig else None,
            "within_2sigma": within / len(errs) if errs else None,
            "latency_ms": statistics.median(float(r["latency_ms"]) for r in rows if r["latency_ms"])
            if any(r["latency_ms"] for r in rows) else None}


def session(arducopter: str, sensor: str, modes, speeds, hovers, avoid: dict, work: Path,
            instance: int = 0, sets=()) -> tuple[list, list]:
    port = h.free_udp_port()
    sitl = h.Sitl(arducopter, work / f"sitl-{sensor}", port, log=lambda s: None, instance=instance).start()
    daemon = None
    flights, hovered = [], []
    try:
        h.prepare(sitl, sensor, avoid)
        daemon = h.start_daemon(port, work / f"truth-{sensor}.csv", work / f"daemon-{sensor}.log", sets=sets)
        assert sitl.wait(lambda: sitl.rec.north, 120), "no pose from SITL"
        sitl.set_mode(h.GUIDED)
        sitl.arm(force=True)       # the branch is out of view on the ground: the daemon is blind there
        time.sleep(2.0)
        sitl.takeoff(h.ALT_M)
        for mode in modes:
            for v in speeds:
                r = h.approach(sitl, mode, v)
                lat = h.capture_to_autopilot_ms(work / f"truth-{sensor}.csv", sitl.rec.forwarded, r.t0, r.t1)
                r.latency_ms = statistics.median(lat) if lat else None
                r.latency_n = len(lat)
                flights.append((sensor, r))
                print(f"{sensor:4s} {mode:7s} {v:4.1f} m/s  closest {r.closest_m:+.2f} m  "
                      f"{'stopped' if r.stopped else 'moving '}  lag "
                      f"{'-' if r.reading_lag_m is None else f'{r.reading_lag_m:+.2f} m'}  "
                      f"({r.readings} autopilot readings); capture->autopilot "
                      f"{'-' if r.latency_ms is None else f'{r.latency_ms:.0f} ms'} (median of {r.latency_n})",
                      flush=True)
        for d in hovers:
            res = hover(sitl, work / f"truth-{sensor}.csv", d)
            hovered.append((sensor, res))
            print(f"{sensor:4s} hover {d:.0f} m: {res}", flush=True)
        sitl.set_mode(h.LAND)
    finally:
        h.stop(daemon)
        sitl.close()
    return flights, hovered


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", nargs="+", default=["prx", "rf"], choices=sorted(h.SENSORS))
    ap.add_argument("--modes", nargs="+", default=["Guided", "Loiter"], choices=["Guided", "Loiter"])
    ap.add_argument("--speeds", nargs="+", type=float, default=[0.5, 1.0, 2.0])
    ap.add_argument("--hover", nargs="*", type=float, default=[2.0, 3.0, 4.0, 5.0])
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="an avoidance parameter")
    ap.add_argument("--keep", metavar="DIR", help="keep SITL, daemon and truth logs here")
    ap.add_argument("--daemon-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a run-config override for the daemon (uav-depth sitl --set)")
    ap.add_argument("--instance", type=int, default=0, help="SITL -I (TCP 5760 + 10 I), to run beside another")
    args = ap.parse_args(argv)
    arducopter = h.binary()
    if arducopter is None:
        print(f"needs the ArduCopter SITL binary: set {h.ENV_BINARY}=/path/to/arducopter (docs/sitl.md)")
        return 2
    avoid = dict(h.AVOID)
    for item in args.set:
        name, _, value = item.partition("=")
        avoid[name] = float(value)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="sitl-ardupilot-"))
    print(f"avoidance: {avoid}; logs in {work}")
    flights, hovered = [], []
    for sensor in args.sensors:
        f, hv = session(arducopter, sensor, args.modes, args.speeds, args.hover, avoid, work, args.instance, args.daemon_set)
        flights += f
        hovered += hv
    print("\nsensor mode    speed  closest approach  stopped  reading lag  capture->autopilot (median)")
    for sensor, r in flights:
        lag = "-" if r.reading_lag_m is None else f"{r.reading_lag_m:+.2f} m"
        lat = "-" if r.latency_ms is None else f"{r.latency_ms:.0f} ms"
        print(f"{sensor:6s} {r.mode:7s} {r.speed:4.1f}   {r.closest_m:+.2f} m{'' if r.closest_m >= 0.3 else ' (<0.3)':7s}"
              f"    {'yes' if r.stopped else 'no ':3s}      {lag:8s}     {lat}")
    print("\nsensor hover  frames measured  median error       median sigma  |err|<=2 sigma  latency (capture->estimate)")
    for sensor, x in hovered:
        if x["err_m"] is None:
            print(f"{sensor:6s} {x['d']:.0f} m    {x['frames']:4d}   0")
            continue
        print(f"{sensor:6s} {x['d']:.0f} m    {x['frames']:4d}   {x['measured']:4d}    {x['err_m']:+.3f} m "
              f"({x['err_pct']:+.1f} %)  {x['sigma_m']:.3f} m       {100 * x['within_2sigma']:.0f} %"
              f"            {x['latency_ms']:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
