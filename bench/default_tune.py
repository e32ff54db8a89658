"""A default tune as a new user runs it: its wall time and its longest silence on a terminal.

Runs, in a fresh directory, the two commands of docs/tuning.md's first example

    uav-depth synth --frames 8 --width 640 --height 360 --focal-px 350 syn
    uav-depth tune syn --population 8 --generations 3 --out p.yaml --report r/

the second under a pseudo-terminal (so the progress bar and the phase lines print, as they do for a user), and
prints its exit status, its wall time, the longest time its terminal showed nothing new, and what it printed
just before and after that silence. The goal: at most 3 minutes on 2 cores, no silence over 5 s.

The first run is a new user's: an empty cache (``XDG_CACHE_HOME`` in the work directory), so the safety sweep is
rendered; ``--again`` runs the same tune once more on the kept cache (a second tune on the same rig).

    python bench/default_tune.py                          # the command above, in a temporary directory
    python bench/default_tune.py --again                  # and again with the sweep cached
    python bench/default_tune.py --keep /tmp/dt -- --safety-sweep quick     # extra tune arguments after --
"""

from __future__ import annotations

import argparse
import fcntl
import os
import pty
import resource
import select
import signal
import shutil
import struct
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

from uav_depth.cli.benchmark import machine_line

SYNTH = ["synth", "--frames", "8", "--width", "640", "--height", "360", "--focal-px", "350", "syn"]
TUNE = ["tune", "syn", "--population", "8", "--generations", "3", "--out", "p.yaml", "--report", "r"]
#: The goals the benchmark prints beside its readings.
GOAL_WALL_S, GOAL_SILENCE_S = 180.0, 5.0


def uav_depth() -> list[str]:
    """How to start the command line of this interpreter's install."""
    exe = Path(sys.executable).with_name("uav-depth")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "uav_depth.cli.main"]


def run_on_terminal(argv: list[str], cwd: str, timeout_s: float, env: dict | None = None
                    ) -> tuple[int, float, list[tuple[float, str]]]:
    """(exit status, wall s, [(seconds since start, text)] of every chunk it wrote) of ``argv`` on a pty."""
    master, slave = pty.openpty()
    # a terminal window of 120 x 40, as a user's: a fresh pty has none, and the progress bar sizes itself by it
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, cwd=cwd, stdin=slave, stdout=slave, stderr=slave, close_fds=True, env=env,
                            start_new_session=True)   # its workers die with it on a timeout
    os.close(slave)
    chunks: list[tuple[float, str]] = []
    while True:
        if time.monotonic() - t0 > timeout_s:
            os.killpg(proc.pid, signal.SIGKILL)
        ready, _, _ = select.select([master], [], [], 0.1)
        if ready:
            try:
                data = os.read(master, 65536)
            except OSError:         # the child closed its side
                data = b""
            if not data:
                break
            chunks.append((time.monotonic() - t0, data.decode(errors="replace")))
        elif proc.poll() is not None:
            break
    rc = proc.wait()
    os.close(master)
    return rc, time.monotonic() - t0, chunks


def longest_silence(chunks: list[tuple[float, str]], wall_s: float) -> tuple[float, int]:
    """(longest gap s between two outputs, or from the start / to the end, index of the chunk after it)."""
    stamps = [0.0] + [t for t, _ in chunks] + [wall_s]
    gaps = [(b - a, i) for i, (a, b) in enumerate(zip(stamps, stamps[1:]))]
    return max(gaps) if gaps else (wall_s, 0)


def measure(work: str, argv: list[str], timeout_s: float, env: dict, label: str) -> bool:
    """One tune on a terminal: prints its tail and readings; True when it met both goals."""
    print(f"$ uav-depth {' '.join(argv[len(uav_depth()):])}    ({label})")
    cpu0 = _children_cpu()
    rc, wall, chunks = run_on_terminal(argv, work, timeout_s, env)
    cpu = _children_cpu() - cpu0
    gap, after = longest_silence(chunks, wall)
    visible = [(t, text.replace("\r", "\n").strip()) for t, text in chunks]
    before_text = next((text for t, text in reversed(visible[:after]) if text), "(the start)")
    after_text = next((text for t, text in visible[after:] if text), "(the end)")
    transcript = os.path.join(work, f"transcript-{label.split(',')[0].replace(' ', '-')}.txt")
    with open(transcript, "w") as fh:
        fh.writelines(f"{t:8.2f} {text}\n" for t, text in visible if text)
    tail = "".join(text for _, text in chunks)[-1500:]
    print(tail.replace("\r", "\n"))
    print(f"load after: {_load()}")
    print(f"{label}: exit status {rc}; wall {wall:.1f} s (goal <= {GOAL_WALL_S:.0f}); longest silence {gap:.1f} s "
          f"(goal <= {GOAL_SILENCE_S:.0f}); CPU time of the tune and its workers {cpu:.0f} s (on {os.cpu_count()} "
          f"idle cores at least {cpu / (os.cpu_count() or 1):.0f} s of wall time)")
    print(f"  silent after: {before_text.strip()[-160:]!r}")
    print(f"  until:        {after_text.strip()[:160]!r}")
    print(f"  every line with its time: {transcript}")
    return rc in (0, 1) and wall <= GOAL_WALL_S and gap <= GOAL_SILENCE_S


def _children_cpu() -> float:
    """User + system CPU seconds of every finished child process (the tune and the workers it joined)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f} (1/5/15 min)"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep", default=None, help="work in this directory (kept) instead of a temporary one")
    ap.add_argument("--timeout", type=float, default=900.0, help="stop the tune after this many seconds")
    ap.add_argument("--again", action="store_true", help="then run the same tune with the sweep cached")
    ap.add_argument("--cache", default=None, help="XDG_CACHE_HOME for the tune (default: an empty one in the work "
                    "directory; one that holds the sweep measures a tune on a rig seen before)")
    ap.add_argument("extra", nargs="*", help="more tune arguments (after --)")
    args = ap.parse_args()
    work = args.keep or tempfile.mkdtemp(prefix="default-tune-")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    cache = args.cache or os.path.join(work, "cache")          # by default a new user's empty cache
    env = dict(os.environ, XDG_CACHE_HOME=cache)
    cached = any(Path(cache).glob("uav-depth/safety-sweep/*/sweep.json"))
    print(machine_line())
    print(f"load before: {_load()}")
    subprocess.run(uav_depth() + SYNTH, cwd=work, check=True, stdout=subprocess.DEVNULL)
    ok = measure(work, uav_depth() + TUNE + args.extra, args.timeout, env,
                 "tune, sweep cached" if cached else "first tune, empty cache")
    if args.again:
        shutil.rmtree(os.path.join(work, "r"), ignore_errors=True)
        ok = measure(work, uav_depth() + TUNE + args.extra, args.timeout, env, "again, sweep cached") and ok
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
