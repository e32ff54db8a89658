"""Tuning on real pairs: Middlebury 2006 (17 scenes, dense ground truth), tune on 6, report on 11.

As a user would: each scene becomes a session (its pair written in the log layout),
its ground truth attached with ``uav-depth reference import`` (middlebury-png, value/3
px, 0 unknown), then ``uav-depth tune`` on the 6 training sessions (held-out by
session inside them for the choice) and ``uav-depth evaluate --json`` on the other 11.
Every row of the table is scored on the same 11 held-out scenes in the benchmark
convention (uav_depth.tuning.metrics: KITTI-style hole filling, GT pixels only,
left strip left out) on the map the daemon ranges on.

    nice python bench/tune_real.py --data DIR [--work /tmp/tune_real] [--population 10 --generations 6]
    # the flight file alone (branch distance as it flies, held out):
    nice python bench/tune_real.py --data DIR --skip-default --skip-ga-paper --skip-synthetic

Each session carries a branch truth: the daemon's ranging on its ground truth (what a perfect
matcher would report), so the flown fitness and the gate's farther check see distances; the
flight file's rows range as the daemon flies (``core.disparity.flight_pipeline`` + its Ranger).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

#: Middlebury 2006 ThirdSize: focal 3740 px full size / 3, baseline 160 mm.
FOCAL_PX, BASELINE_M = 3740.0 / 3.0, 0.160
#: Fixed split (alphabetical scene list, every third scene from the second: textured and weak ones on both sides).
TRAIN = ("Baby2", "Bowling2", "Cloth2", "Lampshade1", "Midd2", "Rocks2")


def cli(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True)
    if check and proc.returncode != 0:
        raise SystemExit(f"uav-depth {' '.join(map(str, args[:2]))} failed ({proc.returncode}): {proc.stderr.strip()}")
    return proc


def truth_distance(gt: np.ndarray, cal) -> float | None:
    """The daemon's ranging on the ground truth (the distance a perfect matcher would report), in its default
    ROI: the branch truth each session carries, so the flown fitness and the farther gate see real distances."""
    from uav_depth.core.disparity import DisparityResult
    from uav_depth.core.params import DEFAULT_PARAMS
    from uav_depth.core.ranging import Ranger, RangingConfig, resolve_roi

    h, w = gt.shape
    roi = resolve_roi(None, w, h)
    return Ranger(RangingConfig(roi=roi), cal, roi, DEFAULT_PARAMS).measure(DisparityResult(gt, gt, None)).distance_m


def make_sessions(data: Path, work: Path) -> list[str]:
    from uav_depth.core.calibration import Calibration
    from uav_depth.core.session import SessionWriter
    from uav_depth.core.ranging import resolve_roi

    scenes = sorted(p.name for p in data.iterdir() if (p / "view1.png").exists())
    for scene in scenes:
        dest = work / "sessions" / scene
        if (dest / "frames" / "000000_ref.npy").exists() and "branch_distance_m" in (
                json.loads((dest / "frames" / "000000_meta.json").read_text())
                if (dest / "frames" / "000000_meta.json").exists() else {}):
            continue
        left, right = cv2.imread(str(data / scene / "view1.png")), cv2.imread(str(data / scene / "view5.png"))
        h, w = left.shape[:2]
        cal = Calibration(focal_px=FOCAL_PX, baseline_m=BASELINE_M, width=w, height=h)
        raw = cv2.imread(str(data / scene / "disp1.png"), cv2.IMREAD_UNCHANGED).astype(np.float32)
        gt = np.where(raw > 0, raw / 3.0, np.nan).astype(np.float32)
        meta = {"branch_distance_m": truth_distance(gt, cal), "roi": list(resolve_roi(None, w, h)),
                "note": "branch truth: the daemon's ranging on the ground-truth disparity"}
        SessionWriter(dest, cal).write(0, left, right, meta=meta)
        cli("reference", "import", dest, "--from", data / scene, "--pattern", "disp1.png",
            "--format", "middlebury-png", "--scale", "3")
    return scenes


def link_split(work: Path, scenes: list[str]) -> tuple[Path, Path]:
    train, test = work / "train", work / "test"
    for d, names in ((train, [s for s in scenes if s in TRAIN]), (test, [s for s in scenes if s not in TRAIN])):
        d.mkdir(parents=True, exist_ok=True)
        for n in names:
            if not (d / n).exists():
                os.symlink(work / "sessions" / n, d / n)
    return train, test


def evaluate(test: Path, params: Path | None) -> dict:
    args = ["evaluate", test, "--json"] + (["--params", params] if params else [])
    return json.loads(cli(*args).stdout)


def tune(train: Path, out: Path, *extra: str) -> tuple[dict, float, int]:
    """``uav-depth tune`` as a user runs it (--force: every row gets its file, the gate is reported);
    returns its summary, wall seconds and exit code of the same run without --force semantics."""
    report = out.with_suffix("")
    store = report / "store.sqlite"
    if store.exists():
        store.unlink()
    t0 = time.perf_counter()
    proc = cli("tune", train, "--out", out, "--report", report, "--no-progress", "--force", *extra)
    wall = time.perf_counter() - t0
    summary = json.loads((report / "summary.json").read_text())
    return summary, wall, proc.returncode


def branch_errors(test: Path, params_file: Path | None) -> list[float | None]:
    """Per scene: signed relative error (fraction, + = farther than the truth; None = no measurement) of the
    daemon's ranging as it flies (core.disparity.flight_pipeline: measured + confidence, near check, fine pass;
    then the daemon's Ranger) against the same ranging on the ground truth, ranging ROI = the daemon's default."""
    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.params import DEFAULT_PARAMS, load_params
    from uav_depth.core.session import iter_frames
    from uav_depth.core.ranging import Ranger, RangingConfig, resolve_roi

    params = load_params(params_file) if params_file else DEFAULT_PARAMS
    pipeline = flight_pipeline(params)
    out = []
    for rec in iter_frames(test, require_reference=True):
        left, right = rec.load_pair()
        gt = rec.load_reference()
        h, w = gt.shape
        cal = rec.session.calibration()
        truth = truth_distance(gt, cal)
        roi = resolve_roi(None, w, h)
        got = Ranger(RangingConfig(roi=roi), cal, roi, params).measure(pipeline.run(left, right)).distance_m
        out.append(None if got is None or truth is None else (got - truth) / truth)
    return out


def branch_line(errs: list[float | None]) -> str:
    """Mean error with a miss counted 100 % (metrics.branch_error), median |e|, misses, farther > 2 %."""
    from uav_depth.tuning.metrics import FARTHER_TOL_PCT

    pct = [100.0 if e is None else abs(e) * 100.0 for e in errs]
    got = [abs(e) * 100.0 for e in errs if e is not None]
    far = sum(e is not None and e * 100.0 > FARTHER_TOL_PCT for e in errs)
    return (f"mean {np.mean(pct):.2f}% (miss = 100 %), median |e| {np.median(got) if got else float('nan'):.2f}%, "
            f"{sum(e is None for e in errs)} no measurement, {far} farther > {FARTHER_TOL_PCT:g}%")


def _pct(e: float | None) -> str:
    return "miss" if e is None else f"{e * 100.0:+.1f}"


def change(base: float, new: float) -> float:
    return (new - base) / abs(base) * 100.0 if base else float("nan")


def table(rows: dict[str, dict], metrics: tuple[str, ...]) -> list[str]:
    """Train (the 6 tuning scenes) and held-out (the other 11) means, change against the baseline, and how many
    held-out scenes got more than 5 % worse (named below the table)."""
    base = rows["manual baseline"]
    lines = ["| row | " + " | ".join(f"train {m} | held-out {m} | change | scenes worse >5%" for m in metrics)
             + " | density |", "|---|" + "---|---|---|---|" * len(metrics) + "---|"]
    for name, doc in rows.items():
        cells = []
        for m in metrics:
            mean = doc["mean"][m]
            worse = [i for a, b, i in zip(base["per"][m], doc["per"][m], doc["ids"]) if change(a, b) > 5.0]
            tr = doc["train"]["mean"][m]
            cells += [f"{tr:.3f}" + ("" if doc is base else f" ({change(base['train']['mean'][m], tr):+.1f}%)"),
                      f"{mean:.3f}", "" if doc is base else f"{change(base['mean'][m], mean):+.1f}%",
                      "" if doc is base else f"{len(worse)}/{len(doc['per'][m])}"]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {doc['mean']['density']:.3f} |")
    lines.append("")
    for name, doc in rows.items():
        if doc is base:
            continue
        for m in metrics:
            worse = [f"{i.split('/')[0]} {change(a, b):+.0f}%" for a, b, i in
                     zip(base["per"][m], doc["per"][m], doc["ids"]) if change(a, b) > 5.0]
            if worse:
                lines.append(f"- {name}, {m} worse >5%: {', '.join(worse)}")
    return lines


def scores(test: Path, params: Path | None, train: Path | None = None) -> dict:
    doc = evaluate(test, params)
    out = {"mean": doc["mean"], "per": {m: [f[m] for f in doc["frames"]] for m in ("mae", "bad2", "density")},
           "ids": [f["id"] for f in doc["frames"]]}
    if train is not None:
        out["train"] = scores(train, params)
    return out


def synthetic_flight(work: Path, root: Path, population: int, generations: int) -> list[str]:
    """The flight file tuned on 4 synthetic frames, branch error on 4 others (leafy scenes, exact truth)."""
    syn = work / "synthetic"
    for name, seed in (("train", 21), ("test", 22)):
        if not (syn / name / "frames" / "000003_left.png").exists():
            cli("synth", syn / name, "--frames", "4", "--seed", str(seed))
    flight = root / "deploy" / "params-flight.yaml"
    summary, wall, _ = tune(syn / "train", work / "syn-flight.yaml", "--base", flight, "--holdout", "0.5",
                            "--population", str(population), "--generations", str(generations))
    base, tuned = evaluate(syn / "test", flight), evaluate(syn / "test", work / "syn-flight.yaml")
    gate = "beat" if summary["gate"]["beats_base"] else "did NOT beat"
    return [f"synthetic flight file: tuned on 4 frames ({wall:.0f} s; {gate} its base on the "
            f"{summary['gate']['frames']} {summary['gate']['on']} frame(s) of them); "
            f"4 other frames: branch error {base['mean']['branch_err_pct']:.2f}% -> {tuned['mean']['branch_err_pct']:.2f}%, "
            f"mae {base['mean']['mae']:.3f} -> {tuned['mean']['mae']:.3f} px"]


def _note(name: str, summary: dict, wall: float, code: int) -> str:
    """One line on a tune: its time, failures, folds, the choice's and the gate's figures and what it chose."""
    sel, cmp, gate = summary["selection"], summary["comparison"], summary["gate"]
    chosen, base = sel["candidates"][sel["winner"]], sel["candidates"][0]
    folds = sel.get("folds") or []
    failed = sum(r["failed"] for r in summary["runs"])
    return (f"{name}: {wall:.0f} s, {summary['evaluated']} evaluated in fold 1 ({failed} of its "
            f"{sum(r['proposals'] for r in summary['runs'])} proposals failed), {len(folds)} fold(s); "
            f"chosen on {sel['on']} ({'beats' if sel['beats_base'] else 'does NOT beat'} the base there"
            f"{'' if code == 0 else ', the gate would refuse it'}); its own metric "
            f"{summary['config']['metric']} train {base['train']:.4g} -> {chosen['train']:.4g}, validation "
            f"{base['validation']:.4g} -> {chosen['validation']:.4g}, {gate['on']} {gate['base']:.4g} -> "
            f"{gate['tuned']:.4g}"
            + "".join(f"; fold {f['fold']} train {f['base_train']:.4g}->{f['winner_train']:.4g} validation "
                      f"{f['base_validation']:.4g}->{f['winner_validation']:.4g}" for f in folds)
            + f"; chosen sgbm {summary['chosen']['params']['sgbm']}"
            + f"; train mae {cmp['train']['metrics'].get('mae', {}).get('tuned', float('nan')):.3f}")


def tuned_rows(args, work: Path, train: Path, test: Path, budget: list[str], t_start: float):
    """The manual baseline and each tune's file on the held-out scenes, and a note per tune."""
    rows: dict[str, dict] = {"manual baseline": scores(test, None, train)}
    notes = []
    runs = [("tune (default: tpe, flown)", work / "tuned.yaml", ()),
            ("ga-paper (faithful: mse, WLS map)", work / "ga-paper.yaml", ("--optimizer", "ga-paper"))]
    runs = [r for r, skip in zip(runs, (args.skip_default, args.skip_ga_paper)) if not skip]
    for spec in args.row:
        label, _, extra = spec.partition(":")
        runs.append((label, work / f"row-{len(runs)}.yaml", tuple(extra.split())))
    for name, out, extra in runs:
        summary, wall, code = tune(train, out, *budget, *extra)
        rows[name] = scores(test, out, train)
        print(f"  {name}: tuned and scored at {time.perf_counter() - t_start:.0f} s", flush=True)
        notes.append(_note(name, summary, wall, code))
    return rows, notes


def flight_section(work: Path, root: Path, train: Path, test: Path, budget: list[str], flight_args) -> None:
    """The flight file, tuned on the real training scenes: does the daemon's distance improve held out?"""
    flight = root / "deploy" / "params-flight.yaml"
    summary, wall, _ = tune(train, work / "flight-tuned.yaml", "--base", flight, *budget, *flight_args)
    b, t = branch_errors(test, flight), branch_errors(test, work / "flight-tuned.yaml")
    fb, ft = scores(test, flight), scores(test, work / "flight-tuned.yaml")
    gate = summary["gate"]
    far = gate["farther"]
    print(f"\nflight file on real pairs ({wall:.0f} s to tune; the gate {'REFUSES' if gate['refused'] else 'writes'} "
          f"it: {'beats' if gate['beats_base'] else 'does NOT beat'} its base on the {gate['frames']} {gate['on']} "
          f"frames of the training scenes, farther > 2 % there {far.get('base')} -> {far.get('tuned')} of "
          f"{far.get('frames')}); held-out ({len(b)} scenes) ranging distance as it flies vs the same ranging on "
          "ground truth:")
    print(f"  flight file:       {branch_line(b)}")
    print(f"  tuned flight file: {branch_line(t)}")
    print("  per scene (base -> tuned, signed %): " + ", ".join(
        f"{i.split('/')[0]} {_pct(x)} -> {_pct(y)}" for i, x, y in zip(fb["ids"], b, t)))
    print(f"  mae in its region {fb['mean']['mae']:.3f} -> {ft['mean']['mae']:.3f} px; chosen sgbm "
          f"{summary['chosen']['params']['sgbm']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the middlebury2006 folder (17 scene folders)")
    ap.add_argument("--work", default="/tmp/tune_real")
    ap.add_argument("--population", type=int, default=10)
    ap.add_argument("--generations", type=int, default=6)
    ap.add_argument("--workers", default="2")
    ap.add_argument("--skip-synthetic", action="store_true")
    ap.add_argument("--row", action="append", default=[],
                    help="another row, 'LABEL:TUNE ARGS' (e.g. 'tpe flown-bad2:--metric flown-bad2')")
    ap.add_argument("--skip-flight", action="store_true")
    ap.add_argument("--flight-args", default="", type=lambda t: tuple(t.split()),
                    help="more uav-depth tune arguments for the flight-file row (e.g. '--keys default,sgbm.mode')")
    ap.add_argument("--skip-default", action="store_true")
    ap.add_argument("--skip-ga-paper", action="store_true")
    args = ap.parse_args()
    from uav_depth.cli.benchmark import machine_line

    t_start = time.perf_counter()
    root = Path(__file__).resolve().parent.parent
    work = Path(args.work)
    scenes = make_sessions(Path(args.data), work)
    train, test = link_split(work, scenes)
    budget = ["--population", str(args.population), "--generations", str(args.generations),
              "--workers", args.workers]
    print(machine_line())
    print(f"train (tune): {', '.join(sorted(TRAIN))}; held-out (report): "
          f"{', '.join(s for s in scenes if s not in TRAIN)}; budget {args.population} x {args.generations}")
    rows, notes = tuned_rows(args, work, train, test, budget, t_start)
    print("\nTrain (6 tuning scenes) and held-out (11 other scenes), benchmark convention, the map the daemon "
          "ranges on, whole frame:\n")
    print("\n".join(table(rows, ("mae", "bad2"))))
    print("\ndensity (held-out mean): " + ", ".join(f"{n} {d['mean']['density']:.3f}" for n, d in rows.items()))
    for n in notes:
        print("- " + n)
    if not args.skip_flight:
        flight_section(work, root, train, test, budget, args.flight_args)
        if not args.skip_synthetic:
            for line in synthetic_flight(work, root, args.population, args.generations):
                print(line)
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
