"""The flight file tuned on leafy synthetic scenes: does the daemon's branch distance improve on other scenes?

As a user would: ``--train`` leafy scenes (bench/leafy_suite.py's generator, indices
from 1000 so none is in the suite) are written as sessions, one frame each, with the
exact reference disparity and the truth of the nearest significant object in the
ranging region; ``uav-depth tune --base deploy/params-flight.yaml`` tunes on them
(held-out by session inside them, k-fold, for the choice and the gate). The base and
the tuned file are then measured as the daemon flies on the leafy suite's own scenes
0..``--scenes``-1 (never trained on): pipeline, Ranger, DISTANCE_SENSOR report.

    nice python bench/tune_leafy.py [--train 8] [--scenes 30] [--population 10 --generations 6]
                                    [--tune-args '--folds 3 ...'] [--also LABEL:FILE ...] [--real DIR]
                                    [--sweep-sessions]

Columns: the mean branch error (plain, symmetric; a miss = 100 %), the safety-weighted
one the flown fitness uses (``metrics.safe_branch_error``: farther than the truth by
more than 2 % costs 100 % + the error), and the counts of scenes without a
measurement and read farther than the truth by more than 2 % and 5 %. ``--also``
measures other parameter files in the same run (e.g. one tuned by an earlier fitness).
The tune runs with ``--force``; when its gate refused, the refusal is printed.

``--real DIR`` (the 17 Middlebury 2006 pairs) adds real data: bench/tune_real.py's six
training scenes join the training log as sessions (with their branch truth), the gate
holds out the last third of the leafy sessions and the last two of those six (Midd2,
Rocks2), and both files are also measured on the other 11 real scenes as the daemon
flies (bench/real_ranging.py: the ranging on the pipeline's output against the same
ranging on the ground truth).

``--sweep-sessions`` adds 60 sessions of the scenes the tuner's safety sweep judges
(``SWEEP_SESSIONS``: plain and varied branches, and the sweep's own leafy variant, on
seeds neither sweep uses), each variant's last seed held out, so that the search sees
the precision and the farther readings the sweep will judge its candidates on.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from leafy_compare import compare
from leafy_suite import scene
from scenebench import FLIGHT_FILE, fmt_pct, render_cached

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.params import load_params
from uav_depth.tuning.metrics import FARTHER_TOL_PCT

#: Training scenes are drawn from this index on (the suite uses 0..N-1).
TRAIN_FROM = 1000


def _write(dest: Path, cfg, note: str) -> None:
    """One session of one frame at ``dest``: ``cfg`` rendered, its exact disparity as the reference, the truth of
    the nearest significant object in the centre region as its branch distance (skipped when already written)."""
    from uav_depth.core.session import SessionWriter

    if (dest / "frames" / "000000_ref.npy").exists():
        return
    fr = render_cached(cfg)
    ref = np.where(fr.disparity > 0, fr.disparity, np.nan).astype(np.float32)
    SessionWriter(dest, cfg.calibration).write(
        0, fr.left, fr.right, reference=ref,
        meta={"branch_distance_m": fr.truth_m, "roi": list(cfg.center_roi), "scene": cfg.to_dict()},
        reference_source={"kind": "synthetic", "exact": True, "note": f"ray-cast ground truth ({note})"})


def write_sessions(root: Path, n: int) -> Path:
    for i in range(TRAIN_FROM, TRAIN_FROM + n):
        _write(root / f"leafy{i}", scene(i), "leafy suite")
    return root


#: ``--sweep-sessions``: the scene variants the tuner's safety sweep judges (uav_depth.sim.sweep.VARIANTS), on seeds
#: neither the safety sweep (10-14) nor the near sweep (0-9) uses; per variant (seeds, branch distances in m). The
#: last seed of each is held out. docs/tuning.md, *Measured again (2026-12-06, morning)*.
SWEEP_SESSIONS = {"plain": ((20, 21, 22), (0.45, 0.8, 1.4, 2.4)),
                  "varied": ((20, 21, 22), (0.45, 0.8, 1.4, 2.4)),
                  "leafy": ((20, 21, 22, 23), tuple(round(0.4 + 0.3 * i, 2) for i in range(9)))}


def write_sweep_sessions(root: Path) -> list[str]:
    """SWEEP_SESSIONS written into ``root``, named ``<variant><seed>_<cm>`` (leafy: ``sweepleafy``, apart from
    the leafy suite's sessions); the names of the held-out ones."""
    from uav_depth.sim.sweep import VARIANTS

    held = []
    for variant, (seeds, distances) in SWEEP_SESSIONS.items():
        prefix = "sweepleafy" if variant == "leafy" else variant
        for seed in seeds:
            for d in distances:
                name = f"{prefix}{seed}_{int(round(d * 100))}"
                _write(root / name, VARIANTS[variant](d, seed), f"{variant} sweep scene")
                if seed == seeds[-1]:
                    held.append(name)
    return held


def measure(params_file: Path, scenes: int) -> dict:
    """The leafy suite's scenes 0..``scenes``-1 as the daemon flies (bench/leafy_compare.py's per-scene rows)."""
    rows = [r[str(params_file)] for r in compare([params_file], 0, scenes)]
    errs = [r["err"] for r in rows]
    got = [abs(e) for e in errs if e is not None]
    return {"mean_branch_err_pct": float(np.mean([r["plain"] for r in rows])),
            "mean_safe_err_pct": float(np.mean([r["safe"] for r in rows])),
            "farther_2pct": sum(e is not None and e > FARTHER_TOL_PCT / 100.0 for e in errs), "median_abs_err": float(np.median(got)) if got else None,
            "mean_abs_err": float(np.mean(got)) if got else None, "no_measurement": sum(e is None for e in errs),
            "farther_5pct": sum(e is not None and e > 0.05 for e in errs), "per_scene": errs}


def measure_real(data: Path, params_file: Path, scenes) -> dict:
    """The real pairs ``scenes`` as the daemon flies (bench/real_ranging.py's reference and calibration)."""
    from real_ranging import evaluate

    rows = evaluate(data, scenes=scenes, sets={"tuned": load_params(params_file)})
    errs = [r["err"] for r in rows]
    got = [abs(e) for e in errs if e is not None]
    return {"mean_abs_err": float(np.mean(got)) if got else None, "no_measurement": sum(e is None for e in errs),
            "within_2pct": sum(r["within"] for r in rows), "farther_2pct": sum(r["farther"] for r in rows),
            "worst": max((e for e in errs if e is not None), key=abs, default=None), "per_scene": dict(zip(scenes, errs))}


def add_real(data: Path, work: Path, train_dir: Path) -> tuple[list[str], list[str]]:
    """Link bench/tune_real.py's six training scenes into ``train_dir``; (their names, the 11 report scenes)."""
    from tune_real import TRAIN, make_sessions

    scenes = make_sessions(data, work / "real")
    for name in TRAIN:
        link = train_dir / name
        if not link.exists():
            link.symlink_to((work / "real" / "sessions" / name).resolve(), target_is_directory=True)
    return list(TRAIN), [s for s in scenes if s not in TRAIN]


def print_tune(summary: dict, proc, args, tune_s: float) -> None:
    """What the tune chose, its gate's figures on the test frames and each fold's train and validation values."""
    sel, gate = summary["selection"], summary["gate"]
    print(proc.stdout.strip().splitlines()[0])
    refused = [ln for ln in proc.stdout.splitlines() + proc.stderr.splitlines() if "--force" in ln]
    if refused:
        print("gate (overridden by --force here): " + refused[0].strip())
    print(f"tuned on {args.train} leafy scenes ({TRAIN_FROM}..{TRAIN_FROM + args.train - 1}) in {tune_s:.0f} s, "
          f"{args.population} x {args.generations} per fold, {len(sel.get('folds') or [1])} fold(s); gate: "
          f"{'beats' if gate['beats_base'] else 'does NOT beat'} the base on the {gate['frames']} {gate['on']} "
          f"frame(s); chosen sgbm {summary['chosen']['params']['sgbm']}")
    far = gate["farther"]
    print(f"  gate's farther > 2 % count on the {gate['on']} frames: base {far.get('base')} -> tuned "
          f"{far.get('tuned')} of {far.get('frames')}")
    sweep = gate.get("safety_sweep")
    if sweep:
        print(f"  safety sweep ({sweep['frames']} synthetic near-sweep frames at the log's rig): farther > 2 % base "
              f"{sweep['base']} -> tuned {sweep['tuned']}")
    for f in sel.get("folds") or []:
        print(f"  fold {f['fold']}: {args.metric} train {f['base_train']:.3f} -> {f['winner_train']:.3f}, "
              f"validation {f['base_validation']:.3f} -> {f['winner_validation']:.3f}")


def print_measured(args, out: Path, real_report) -> None:
    """The flight file and the tuned one on the leafy suite's scenes (and the real pairs) as the daemon flies."""
    rows = {"flight file": measure(FLIGHT_FILE, args.scenes), "tuned flight file": measure(out, args.scenes)}
    for spec in args.also:
        label, _, path = spec.partition(":")
        rows[label] = measure(Path(path), args.scenes)
    print(f"\nleafy suite scenes 0..{args.scenes - 1} (never trained on), as the daemon flies and reports:")
    print(f"{'params':18s} {'mean err (miss=100%)':>20s} {'safety-weighted':>15s} {'median |e|':>10s} "
          f"{'mean |e|':>9s} {'no meas':>7s} {'farther>2%':>10s} {'farther>5%':>10s}")
    for name, r in rows.items():
        print(f"{name:18s} {r['mean_branch_err_pct']:19.2f}% {r['mean_safe_err_pct']:14.2f}% "
              f"{fmt_pct(r['median_abs_err']):>10s} {fmt_pct(r['mean_abs_err']):>9s} {r['no_measurement']:7d} "
              f"{r['farther_2pct']:10d} {r['farther_5pct']:10d}")
    if args.real is not None:
        print(f"\nreal pairs {', '.join(real_report)} (never trained on), as the daemon flies, against the ranging "
              "on the ground truth:")
        print(f"{'params':18s} {'mean |e|':>9s} {'within 2%':>9s} {'farther>2%':>10s} {'no meas':>7s} {'worst':>8s}")
        for name, path in (("flight file", FLIGHT_FILE), ("tuned flight file", out)):
            r = measure_real(args.real, path, real_report)
            print(f"{name:18s} {fmt_pct(r['mean_abs_err']):>9s} {r['within_2pct']:>6d}/{len(real_report)} "
                  f"{r['farther_2pct']:10d} {r['no_measurement']:7d} {fmt_pct(r['worst']):>8s}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/tune_leafy")
    ap.add_argument("--train", type=int, default=8)
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--population", type=int, default=10)
    ap.add_argument("--generations", type=int, default=6)
    ap.add_argument("--workers", default="2")
    ap.add_argument("--metric", default="flown")
    ap.add_argument("--tune-args", default="", type=lambda t: tuple(t.split()),
                    help="more uav-depth tune arguments (e.g. '--folds 3 --keys default,sgbm.mode')")
    ap.add_argument("--also", action="append", default=[], metavar="LABEL:FILE",
                    help="measure this parameter file too, in the same run (repeatable)")
    ap.add_argument("--real", type=Path, default=None, metavar="DIR",
                    help="the 17 Middlebury 2006 pairs: train on six of them too, report on the other 11")
    ap.add_argument("--sweep-sessions", action="store_true",
                    help="add plain, varied and leafy branches of the safety sweep's kind (SWEEP_SESSIONS) to the "
                         "log, each variant's last seed held out")
    args = ap.parse_args()
    t0 = time.perf_counter()
    work = Path(args.work)
    sessions = write_sessions(work / "train", args.train)
    held: list[str] = []
    real_report = None
    if args.real is not None or args.sweep_sessions:
        leafy = [f"leafy{i}" for i in range(TRAIN_FROM, TRAIN_FROM + args.train)]
        held = leafy[len(leafy) - len(leafy) // 3:]
    if args.real is not None:
        real_train, real_report = add_real(args.real, work, sessions)
        held = real_train[-2:] + held
    if args.sweep_sessions:
        held += write_sweep_sessions(sessions)
    holdout = ("--holdout", ",".join(held)) if held else ()
    out, report = work / "flight-tuned.yaml", work / "report"
    if (report / "store.sqlite").exists():
        (report / "store.sqlite").unlink()
    print(machine_line())
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "tune", sessions, "--base", FLIGHT_FILE,
                           "--metric", args.metric, "--population", str(args.population), "--generations",
                           str(args.generations), "--workers", args.workers, "--out", out, "--report", report,
                           "--no-progress", "--force", *holdout, *args.tune_args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"uav-depth tune failed ({proc.returncode}): {proc.stderr.strip()}")
    print_tune(json.loads((report / "summary.json").read_text()), proc, args, time.perf_counter() - t0)
    print_measured(args, out, real_report)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
