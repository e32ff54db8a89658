"""How soon after exec `uav-depth run` handles signals, and what it does with one that early.

Spawns ``uav-depth run`` (a synthetic source, nothing listening on the MAVLink
port) ``--runs`` times. For each run it polls ``/proc/PID/status`` until SIGHUP,
SIGINT, SIGUSR1 and SIGTERM are all caught, notes whether NumPy / OpenCV were
mapped yet (``/proc/PID/maps``), sends SIGTERM at once and records the exit code,
the daemon's own "signal handlers installed N ms after exec" figure and the time
the parent saw from spawn to handlers. It also times a bare interpreter
(``python -c pass`` to the same point) for comparison. Prints medians and maxima.

    .venv/bin/python bench/signal_startup.py --runs 10
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WANTED = sum(1 << (s - 1) for s in (signal.SIGHUP, signal.SIGINT, signal.SIGUSR1, signal.SIGTERM))
CONFIG = """source: {kind: synthetic, fps: 5, scene: {width: 320, height: 240, focal_px: 200.0}}
mavlink: {url: "udpout:127.0.0.1:9"}
"""


def caught(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return int(line.split()[1], 16)
    return 0


def one(config: Path) -> dict:
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(config)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while caught(proc.pid) & WANTED != WANTED:
        if proc.poll() is not None:
            raise SystemExit(f"exited early: {proc.stderr.read()}")
        time.sleep(0.0005)
    seen_ms = (time.monotonic() - t0) * 1000
    maps = Path(f"/proc/{proc.pid}/maps").read_text()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    m = re.search(r"signal handlers installed (\d+) ms after exec", err)
    return {"code": proc.returncode, "seen_ms": seen_ms, "self_ms": float(m.group(1)) if m else float("nan"),
            "slow_imports_loaded": "numpy" in maps or "cv2" in maps, "traceback": "Traceback" in err}


def bare() -> float:
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return (time.monotonic() - t0) * 1000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        config = Path(d) / "run.yaml"
        config.write_text(CONFIG)
        runs = [one(config) for _ in range(args.runs)]
    bares = [bare() for _ in range(args.runs)]
    for key in ("self_ms", "seen_ms"):
        vals = [r[key] for r in runs]
        print(f"{key:>8}: median {statistics.median(vals):.0f} ms, max {max(vals):.0f} ms")
    print(f"bare python -c pass (exec to exit): median {statistics.median(bares):.0f} ms, max {max(bares):.0f} ms")
    print(f"exit codes: {sorted({r['code'] for r in runs})}; tracebacks: {sum(r['traceback'] for r in runs)}; "
          f"NumPy/OpenCV already loaded when the handlers were in: {sum(r['slow_imports_loaded'] for r in runs)}"
          f" of {len(runs)}")
    print(f"load average: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
