"""The parameter schema fuzzed against OpenCV, through ``params check`` and a flying daemon (issue 44).

Draws ``--files`` random parameter files the schema accepts (half over each key's whole range,
half with a search range that fits the camera, so that most reach OpenCV) plus every key at
both of its bounds (the other keys at their defaults, a cross rule's partner moved out of the
way) and two hostile files (a 1 KB YAML alias bomb, a file past the 64 KiB cap), then:

1. ``uav-depth params check --calibration CAMERA FILE...``: each file is one line; a child that
   crashed or hung ("OpenCV crashed with SIG...", "did not finish") is a combination OpenCV cannot
   take that the schema accepts, listed with its file. The checking process itself must never die.
2. a real ``uav-depth run`` (synthetic source at the same camera, a pymavlink peer on loopback,
   the systemd unit's scheduling applied as bench/under_load.py applies it; ``--plain``: none)
   flying a good file: each fuzz file replaces the parameter file (rename, as the tuner writes
   it); the daemon judges it (log line); a file it swaps in is replaced by the good one again at
   once. The daemon must never die, and while the good parameters fly (trials included) the
   DISTANCE_SENSOR stream must have no gap over ``--gap-ms``. For the machine's share of the
   gaps, the same figures are taken first over ``--baseline-s`` without reloads, and after
   every fourth refused file over a control window as long as its trial, nothing judged.

Prints one summary (counts, refusal reasons, crashes found, gaps, wall time and load average).

    .venv/bin/python bench/params_fuzz.py --files 2000 --seed 0
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from mavlink_peer import Receiver  # noqa: E402
from under_load import Groups, scheduler, unit_scheduling  # noqa: E402

from uav_depth.core.errors import ConfigError  # noqa: E402
from uav_depth.core.params import (SPECS, check_computable, load_params, params_from_dict,  # noqa: E402
                                   save_params)

CLI = [sys.executable, "-m", "uav_depth.cli.main"]
REPO = Path(__file__).resolve().parents[1]
#: What the daemon flies between fuzz files (and what the bound files start from): the 640x360 flight file.
GOOD = load_params(REPO / "deploy" / "params-flight-640x360.yaml")
JUDGED = re.compile(r"parameters reloaded from|parameters rejected|rewritten with the same parameters")


# -- drawing files the schema accepts -------------------------------------------------------------

def _draw_value(spec, rng: np.random.Generator, fit_px: int | None) -> object:
    if spec.choices:
        return str(rng.choice(spec.choices))
    if spec.kind is bool:
        return bool(rng.integers(2))
    if spec.kind is tuple:
        x = np.sort(rng.uniform(0, 1, 2))
        y = np.sort(rng.uniform(0, 1, 2))
        return [round(float(x[0]), 3), round(float(y[0]), 3), round(float(max(x[1], x[0] + 0.01)), 3),
                round(float(max(y[1], y[0] + 0.01)), 3)]
    lo, hi = float(spec.lo), float(spec.hi)
    if spec.key == "sgbm.num_disparities" and fit_px is not None:
        hi = max(16.0, min(hi, fit_px))
    if spec.key == "sgbm.min_disparity" and fit_px is not None:
        lo, hi = -16.0, 16.0
    # half uniform over the range, half log-uniform towards the low end (where the defaults live)
    if rng.random() < 0.5 or lo < 0:
        v = rng.uniform(lo, hi)
    else:
        v = math.exp(rng.uniform(math.log(max(lo, 1e-3)), math.log(max(hi, 1e-3))))
    if spec.kind is float:
        return round(float(v), 4)
    v = int(round(v))
    if spec.rule == "odd":
        v = v if v % 2 else min(int(hi), v + 1)
    elif spec.rule in ("multiple_of_16", "zero_or_multiple_of_16"):
        v = 16 * int(round(v / 16))
        v = max(16, v) if spec.rule == "multiple_of_16" else v
    return int(min(max(v, spec.lo), spec.hi))


def random_file(rng: np.random.Generator, fit_px: int | None) -> dict:
    """A parameter mapping a parameter file may hold (the schema and check_computable, as load_params
    applies them), drawn again until it is one."""
    while True:
        data: dict = {}
        for spec in SPECS:
            data.setdefault(spec.section, {})[spec.name] = _draw_value(spec, rng, fit_px)
        try:
            check_computable(params_from_dict(data))
        except ConfigError:
            continue
        return data


def bound_files() -> list[tuple[str, dict]]:
    """Every numeric key at its lowest and highest accepted value, the rest at their defaults."""
    out = []
    for spec in SPECS:
        if spec.lo is None or spec.kind is tuple:
            continue
        for which, value in (("lo", spec.lo), ("hi", spec.hi)):
            data = GOOD.to_dict()
            data[spec.section][spec.name] = spec.kind(value) if spec.rule != "odd" or int(value) % 2 else value + 1
            if spec.rule == "positive" and not value > 0:
                data[spec.section][spec.name] = 1e-3
            sg = data["sgbm"]
            if spec.key == "sgbm.p1":
                sg["p2"] = max(sg["p2"], sg["p1"] + 1)
            if spec.key == "sgbm.p2":
                sg["p1"] = min(sg["p1"], sg["p2"] - 1)
            out.append((f"{spec.key}={which}", data))
    for mode in ("sgbm", "sgbm_3way", "hh", "hh4"):           # each mode at the highest uniqueness it takes
        data = GOOD.to_dict()
        data["sgbm"].update(mode=mode, uniqueness_ratio=99 if mode == "sgbm_3way" else 100)
        out.append((f"mode={mode},uniqueness=max", data))
    return out


def hostile_files(root: Path) -> list[tuple[str, Path]]:
    """Files no parser should take long over: a 1 KB alias bomb, a file past the 64 KiB cap."""
    bomb = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    bomb += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, 10)]
    (root / "hostile-alias-bomb.yaml").write_text("\n".join(bomb) + "\n")
    (root / "hostile-oversize.yaml").write_text(yaml.safe_dump(GOOD.to_dict()) + "# padding\n" * 7000)
    return [("hostile: alias bomb", root / "hostile-alias-bomb.yaml"),
            ("hostile: 70 KB", root / "hostile-oversize.yaml")]


def write_files(root: Path, n: int, seed: int, fit_px: int) -> list[tuple[str, Path]]:
    rng = np.random.default_rng(seed)
    named = bound_files() + [(f"random-{i:05d}", random_file(rng, fit_px if i % 2 else None)) for i in range(n)]
    out = hostile_files(root)
    for name, data in named:
        path = root / f"{name.replace('=', '-').replace(',', '_')}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        out.append((name, path))
    return out


# -- phase 1: params check ------------------------------------------------------------------------

def check_all(files: list[tuple[str, Path]], calib: Path, chunk: int = 400) -> dict:
    reasons: collections.Counter = collections.Counter()
    crashes, valid, died = [], 0, []
    for i in range(0, len(files), chunk):
        part = [str(p) for _, p in files[i:i + chunk]]
        proc = subprocess.run([*CLI, "params", "check", "--calibration", str(calib), *part],
                              capture_output=True, text=True)
        if proc.returncode not in (0, 78):
            died.append((part[0], proc.returncode, proc.stderr[-500:]))
        valid += sum(1 for ln in proc.stdout.splitlines() if ": valid, hash " in ln)
        for ln in proc.stderr.splitlines():
            if not ln.startswith("uav-depth params: error: "):
                continue
            if "crashed with SIG" in ln or "did not finish" in ln or "exited with code" in ln:
                crashes.append(ln)
            body = ln.split(": error: ", 1)[1].split(": ", 1)[-1]
            reasons[re.sub(r"(?<![\w.])-?\d+(\.\d+)?(?!\w)", "N", body.split(", but got")[0])[:110]] += 1
    return {"valid": valid, "refused": sum(reasons.values()), "reasons": reasons, "crashes": crashes,
            "checker_died": died}


# -- phase 2: a flying daemon ---------------------------------------------------------------------

class Log:
    """The daemon's stderr, each line stamped with time.monotonic() on arrival."""

    def __init__(self, stream):
        self.lines: list[tuple[float, str]] = []
        self._t = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._t.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    def wait(self, pattern: re.Pattern, since: int, timeout: float) -> tuple[float, str] | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for t, ln in self.lines[since:]:
                if pattern.search(ln):
                    return t, ln
            time.sleep(0.01)
        return None


def replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".new")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def gap_stats(rx: Receiver, windows: list[tuple[float, float]], goal_ms: float) -> dict:
    """DISTANCE_SENSOR arrival gaps (ms) between readings captured inside a window and arrived before its end.

    A reading belongs to a window by its capture stamp (time_boot_ms counts CLOCK_MONOTONIC), so a frame
    captured under a fuzz file's parameters and finished after the good ones returned is not counted.
    """
    readings = [(t, m.time_boot_ms / 1000.0) for t, m in rx.timed("DISTANCE_SENSOR")]
    gaps: list[tuple[float, float, float]] = []      # (ms, from, to)
    n = 0
    for a, b in windows:
        inside = [t for t, cap in readings if cap >= a and t <= b]
        n += len(inside)
        gaps += [((y - x) * 1000.0, x, y) for x, y in zip(inside, inside[1:])]
    ms = sorted(g[0] for g in gaps)
    return {"n": n, "worst": ms[-1] if ms else math.nan, "p99": ms[int(0.99 * (len(ms) - 1))] if ms else math.nan,
            "over": sum(g > goal_ms for g in ms), "top": sorted(gaps, reverse=True)[:5]}


def during(judgements: list[tuple[str, float, float, str]], t_from: float, t_to: float) -> str:
    """Which file's trial (write to judgement) overlapped a gap."""
    names = [f"{name} ({verdict})" for name, w, j, verdict in judgements if w <= t_to and j >= t_from]
    return ", ".join(names) or "no trial running"


def fly_all(files: list[tuple[str, Path]], tmp: Path, scene: dict, baseline_s: float, goal_ms: float,
            plain: bool) -> dict:
    rx = Receiver()
    settings = {} if plain else unit_scheduling()
    groups = Groups(int(settings["CPUWeight"]) if "CPUWeight" in settings else None)
    params = tmp / "flying.yaml"
    save_params(GOOD, params)
    good = params.read_bytes()
    cfg = {"source": {"kind": "synthetic", "fps": 10, "scene": scene}, "params_file": str(params),
           "ranging": {"max_age_ms": 499}, "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 20},
           "service": {"status_interval_s": 5.0, "params_poll_s": 1.0}}
    (tmp / "run.yaml").write_text(yaml.safe_dump(cfg))
    proc = subprocess.Popen([*CLI, "run", "--config", str(tmp / "run.yaml")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, preexec_fn=scheduler(settings, pin=False))
    groups.join("daemon", proc.pid)
    log = Log(proc.stderr)
    out: dict = {"judged": 0, "swapped": 0, "refused": 0, "unjudged": [], "daemon_died": None,
                 "scheduling": (", ".join(f"{k}={v}" for k, v in settings.items()) or "none (--plain)")
                 + ("; " + groups.describe() if settings else "")}
    judgements: list[tuple[str, float, float, str]] = []
    try:
        if log.wait(re.compile("ready:"), 0, 300) is None:
            raise SystemExit("the daemon did not start:\n" + "\n".join(ln for _, ln in log.lines[-20:]))
        t0 = time.monotonic()
        time.sleep(baseline_s)
        out["baseline"] = gap_stats(rx, [(t0, time.monotonic())], goal_ms)
        windows, controls, start = [], [], time.monotonic()
        for name, path in files:
            if proc.poll() is not None:
                out["daemon_died"] = (name, proc.returncode)
                break
            mark, t_write = len(log.lines), time.monotonic()
            replace(params, path.read_bytes())
            hit = log.wait(JUDGED, mark, 120)
            if hit is None:
                out["unjudged"].append(name)
                continue
            out["judged"] += 1
            swapped = "parameters reloaded" in hit[1]
            judgements.append((name, t_write, hit[0], "swapped" if swapped else "refused"))
            if not swapped and len(judgements) % 4 == 0:
                # a control window as long as the trial, nothing judged: the machine's share of the gaps
                t_idle = time.monotonic()
                time.sleep(hit[0] - t_write)
                controls.append((t_idle, time.monotonic()))
            if swapped:
                out["swapped"] += 1
                windows.append((start, hit[0]))
                mark = len(log.lines)
                replace(params, good)
                back = log.wait(re.compile("parameters reloaded from"), mark, 120)
                start = back[0] if back else time.monotonic()
            else:
                out["refused"] += "parameters rejected" in hit[1]
        windows.append((start, time.monotonic()))
        trials = [(w, j) for name, w, j, verdict in judgements]
        out["trials"] = gap_stats(rx, trials, goal_ms)
        out["controls"] = gap_stats(rx, controls, goal_ms)
        out["trial_s"], out["control_s"] = sum(j - w for w, j in trials), sum(b - a for a, b in controls)
        out["fuzz"] = gap_stats(rx, windows, goal_ms)
        out["fuzz"]["top"] = [(ms, during(judgements, a, b)) for ms, a, b in out["fuzz"]["top"]]
        out["fuzz_s"] = time.monotonic() - t0 - baseline_s
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(60)
        elif out["daemon_died"] is None:
            out["daemon_died"] = ("(after the last file)", proc.returncode)
        groups.close()
        rx.close()
    out["tracebacks"] = sum("Traceback" in ln for _, ln in log.lines)
    return out


def report(fly: dict, goal_ms: float) -> bool:
    """Print the daemon's half; True when it held (never died, no gap over the goal while the good flew)."""
    base, fuzz = fly["baseline"], fly.get("fuzz")
    print(f"daemon scheduling (deploy/uav-depth.service): {fly['scheduling']}")
    print(f"daemon: {fly['judged']} judged ({fly['swapped']} swapped in and back, {fly['refused']} refused), "
          f"{len(fly['unjudged'])} not judged within 120 s, died: {fly['daemon_died'] or 'never'}, "
          f"tracebacks {fly['tracebacks']} ({fly.get('fuzz_s', math.nan):.0f} s)")
    for label, st in (("without reloads first", base), ("while the good parameters flew, trials included", fuzz)):
        if st:
            print(f"DISTANCE_SENSOR gaps {label}: {st['n']} readings, worst {st['worst']:.0f} ms, 99th "
                  f"{st['p99']:.0f} ms, over {goal_ms:g} ms: {st['over']}")
    for ms, what in (fuzz or {}).get("top", []):
        print(f"  {ms:6.0f} ms during: {what}")
    if fuzz:
        for label, st, secs in (("during trials (file written to judged)", fly["trials"], fly["trial_s"]),
                                ("in control windows as long, nothing judged", fly["controls"], fly["control_s"])):
            print(f"gaps {label}: {secs:.0f} s, {st['n']} readings, worst {st['worst']:.0f} ms, over "
                  f"{goal_ms:g} ms: {st['over']} ({st['over'] / max(secs, 1e-9) * 60:.1f} a minute)")
    return fly["daemon_died"] is None and fuzz is not None and fuzz["over"] == 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--files", type=int, default=2000, help="random files (besides the bounds)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--gap-ms", type=float, default=200.0)
    ap.add_argument("--baseline-s", type=float, default=20.0)
    ap.add_argument("--skip-daemon", action="store_true", help="only params check")
    ap.add_argument("--plain", action="store_true", help="the daemon without the unit's scheduling")
    args = ap.parse_args()
    t_start = time.monotonic()
    scene = {"width": args.width, "height": args.height, "focal_px": 350.0 * args.width / 640,
             "branch_distance_m": 0.8, "seed": 1}
    with tempfile.TemporaryDirectory(prefix="params-fuzz-") as d:
        tmp = Path(d)
        calib = tmp / "camera.yaml"
        calib.write_text(yaml.safe_dump({"focal_px": scene["focal_px"], "baseline_m": 0.063,
                                         "width": args.width, "height": args.height}))
        files = write_files(tmp, args.files, args.seed, fit_px=args.width // 3)
        print(f"{len(files)} files: 2 hostile, {len(files) - args.files - 2} at a key's bound, {args.files} random "
              f"(seed {args.seed}); camera {args.width}x{args.height}", flush=True)
        t = time.monotonic()
        checked = check_all(files, calib)
        print(f"params check: {checked['valid']} valid, {checked['refused']} refused, "
              f"{len(checked['crashes'])} OpenCV crashes or hangs caught in the child, checker died "
              f"{len(checked['checker_died'])} times ({time.monotonic() - t:.0f} s)", flush=True)
        for reason, n in checked["reasons"].most_common(12):
            print(f"  {n:5d}  {reason}")
        for line in checked["crashes"][:20]:
            print(f"  CRASH {line}")
        for first, code, tail in checked["checker_died"]:
            print(f"  params check DIED (exit {code}) on the chunk from {first}: {tail.strip().splitlines()[-1:]}")
        fly = None if args.skip_daemon else fly_all(files, tmp, scene, args.baseline_s, args.gap_ms, args.plain)
    held = report(fly, args.gap_ms) if fly is not None else True
    print(f"wall time {time.monotonic() - t_start:.0f} s; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs")
    ok = not checked["crashes"] and not checked["checker_died"] and held
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
