"""The daemon with the systemd unit's scheduling beside CPU-bound work on 2 cores (issue 47 item 5).

Runs the real ``uav-depth run`` (synthetic 1280x720 scene, the flight file deploy/params-flight.yaml,
a pymavlink peer on loopback) beside ``--hogs`` CPU-bound processes, everything pinned to the first
two CPUs. The daemon gets deploy/uav-depth.service's scheduling, applied the way systemd applies it:
``Nice=`` with setpriority, ``CPUSchedulingPolicy=``/``CPUSchedulingPriority=`` with
sched_setscheduler, and ``CPUWeight=`` as the daemon's own cgroup's weight (cgroup v2 ``cpu.weight``,
or v1 ``cpu.shares`` = weight x 1024 / 100, as systemd maps it) beside a sibling group of default
weight holding the CPU-bound processes (another service); where no cgroup can be made, the line
says so and the processes share one group. Goals: at least 10 readings a second and no gap over
300 ms between DISTANCE_SENSOR arrivals, over ``--duration`` seconds (2 minutes by default).
``--plain`` runs the daemon without the unit's scheduling, for comparison.

    sudo .venv/bin/python bench/under_load.py [--duration 120] [--hogs 4] [--plain]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from mavlink_peer import Receiver  # noqa: E402

UNIT = REPO / "deploy" / "uav-depth.service"
CPUS = {0, 1}
HOG = "while True: pass"


def unit_scheduling(path: Path = UNIT) -> dict[str, str]:
    """The [Service] scheduling settings of the unit (those this benchmark can apply)."""
    keys = ("Nice", "CPUSchedulingPolicy", "CPUSchedulingPriority", "CPUWeight")
    out = {}
    for line in path.read_text().splitlines():
        key, sep, value = line.strip().partition("=")
        if sep and key in keys:
            out[key] = value.strip()
    return out


class Groups:
    """Two sibling cpu cgroups (the daemon's, weighted as the unit says, and the others', default)."""

    def __init__(self, weight: int | None):
        self.root, self.kind, self.why = None, None, ""
        if weight is None:
            self.why = "CPUWeight not set in the unit"
            return
        for base, kind in ((Path("/sys/fs/cgroup"), "v2"), (Path("/sys/fs/cgroup/cpu"), "v1")):
            ctl = base / ("cpu.weight" if kind == "v2" else "cpu.shares")
            if kind == "v2" and not (base / "cgroup.controllers").exists() or kind == "v1" and not ctl.exists():
                continue
            try:
                self.root = base / f"uav-depth-bench-{os.getpid()}"
                for name, w in (("daemon", weight), ("others", 100)):
                    (self.root / name).mkdir(parents=True)
                    value = str(w) if kind == "v2" else str(w * 1024 // 100)
                    (self.root / name / ("cpu.weight" if kind == "v2" else "cpu.shares")).write_text(value)
                self.kind = kind
                return
            except OSError as exc:
                self.why = f"no writable {kind} cpu cgroup ({exc.strerror})"
                self.close()
        self.why = self.why or "no cpu cgroup controller"

    def join(self, name: str, pid: int) -> None:
        if self.kind is not None:
            (self.root / name / "cgroup.procs").write_text(str(pid))

    def describe(self) -> str:
        return (f"CPUWeight as a {self.kind} cgroup weight beside a default-weight group of the CPU-bound "
                "processes" if self.kind else f"CPUWeight NOT applied: {self.why}")

    def close(self) -> None:
        if self.root is None:
            return
        for name in ("daemon", "others"):
            try:
                for pid in (self.root / name / "cgroup.procs").read_text().split():
                    (self.root.parent / "cgroup.procs").write_text(pid)
                (self.root / name).rmdir()
            except OSError:
                pass
        try:
            self.root.rmdir()
        except OSError:
            pass


def scheduler(settings: dict[str, str], pin: bool = True):
    """A preexec_fn applying Nice and the CPU scheduling policy as systemd does before exec (``pin``: and
    the two CPUs)."""
    def apply() -> None:
        if pin:
            os.sched_setaffinity(0, CPUS)
        if "Nice" in settings:
            os.setpriority(os.PRIO_PROCESS, 0, int(settings["Nice"]))
        policy = settings.get("CPUSchedulingPolicy")
        if policy:
            const = {"other": os.SCHED_OTHER, "batch": os.SCHED_BATCH, "idle": os.SCHED_IDLE,
                     "fifo": os.SCHED_FIFO, "rr": os.SCHED_RR}[policy]
            os.sched_setscheduler(0, const, os.sched_param(int(settings.get("CPUSchedulingPriority", 0))))
    return apply


def start_daemon(tmp: Path, port: int, settings: dict[str, str]) -> subprocess.Popen:
    cfg = {"source": {"kind": "synthetic", "fps": 30,
                      "scene": {"width": 1280, "height": 720, "focal_px": 700.0, "branch_distance_m": 1.2,
                                "seed": 1}},
           "params_file": str(REPO / "deploy" / "params-flight.yaml"),
           "mavlink": {"url": f"udpout:127.0.0.1:{port}", "rate_hz": 30},
           "service": {"status_interval_s": 10.0}}
    (tmp / "run.yaml").write_text(yaml.safe_dump(cfg))
    return subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(tmp / "run.yaml")],
                            stdout=subprocess.DEVNULL, stderr=open(tmp / "daemon.log", "w"),
                            preexec_fn=scheduler(settings))


def gaps(arrivals: list[float]) -> list[float]:
    return [(b - a) * 1000.0 for a, b in zip(arrivals, arrivals[1:])]


def run(args: argparse.Namespace) -> int:
    settings = {} if args.plain else unit_scheduling()
    groups = Groups(None if args.plain or "CPUWeight" not in settings else int(settings["CPUWeight"]))
    rx, hogs, daemon = Receiver(), [], None
    with tempfile.TemporaryDirectory(prefix="under-load-") as d:
        tmp = Path(d)
        try:
            daemon = start_daemon(tmp, rx.port, settings)
            groups.join("daemon", daemon.pid)
            if not rx.wait(lambda: len(rx.of("DISTANCE_SENSOR")) >= 5, 300):
                raise SystemExit("no readings:\n" + (tmp / "daemon.log").read_text()[-2000:])
            for _ in range(args.hogs):
                hog = subprocess.Popen([sys.executable, "-c", HOG], preexec_fn=lambda: os.sched_setaffinity(0, CPUS))
                groups.join("others", hog.pid)
                hogs.append(hog)
            time.sleep(3.0)                       # the scheduler settles with the hogs running
            t0 = time.monotonic()
            time.sleep(args.duration)
            t1 = time.monotonic()
            load = os.getloadavg()[0]
            alive = daemon.poll() is None
        finally:
            for p in hogs + ([daemon] if daemon else []):
                if p.poll() is None:
                    p.terminate()
            for p in hogs + ([daemon] if daemon else []):
                p.wait(60)
            groups.close()
            rx.close()
        status = [ln for ln in (tmp / "daemon.log").read_text().splitlines() if "status:" in ln]
    arrivals = [t for t, m in rx.timed("DISTANCE_SENSOR") if t0 <= t <= t1]
    g = sorted(gaps(arrivals))
    rate = len(arrivals) / (t1 - t0)
    worst_s = min((sum(1 for t in arrivals if a <= t < a + 10) / 10 for a in range(int(t0), int(t1) - 10)),
                  default=float("nan"))
    print(f"scheduling: {', '.join(f'{k}={v}' for k, v in settings.items()) or 'none (--plain)'}; "
          f"{groups.describe() if settings else 'no cgroup'}; pinned to CPUs {sorted(CPUS)} with {args.hogs} "
          f"CPU-bound processes")
    print(f"{len(arrivals)} DISTANCE_SENSOR in {t1 - t0:.0f} s: {rate:.1f} a second (worst 10 s: {worst_s:.1f}); "
          f"gaps: median {g[len(g) // 2] if g else float('nan'):.0f} ms, 99th {g[int(len(g) * 0.99)] if g else float('nan'):.0f} ms, "
          f"max {g[-1] if g else float('nan'):.0f} ms; over 300 ms: {sum(x > 300 for x in g)}")
    print(f"daemon {'ran throughout' if alive else 'DIED'}; last status: {status[-1].split('status: ')[-1] if status else '-'}")
    print(f"load average {load:.1f} on {os.cpu_count()} CPUs (other work on this machine included)")
    ok = alive and rate >= 10 and (not g or g[-1] <= 300)
    print("PASS" if ok else "FAIL", "(goals: >= 10 readings a second, no gap over 300 ms)")
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=120.0, help="seconds measured (after 3 s of settling)")
    ap.add_argument("--hogs", type=int, default=4, help="CPU-bound processes beside the daemon")
    ap.add_argument("--plain", action="store_true", help="without the unit's scheduling, for comparison")
    return run(ap.parse_args())


if __name__ == "__main__":
    sys.exit(main())
