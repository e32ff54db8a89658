"""What ``uav-depth tune`` buys on a rig no shipped parameter file was made for.

A user with another camera starts from the nearest shipped file and tunes on frames of their own. For each rig
of :data:`RIGS` (an OAK-D-like 1280x800 with a 75 mm baseline, a 1920x1080, a cheaper 640x480 camera with more
noise, a gain mismatch between the eyes and blur), as that user would:

1. synthetic sessions with truth at the rig (every other frame a leafy scene: twigs, needles, sky, shadows):
   ``--train-seeds`` sessions to tune on, and ``--held-seeds`` other sessions held out for this benchmark alone;
2. the base: the nearest shipped file (``deploy/params-flight*.yaml`` by image width);
3. ``uav-depth tune TRAIN --base BASE --out tuned.yaml`` with tune's defaults (``--population`` and
   ``--generations`` shrink the budget: say so when you report) and each ``--seeds`` seed;
4. two ceilings, each the same tune on the held-out sessions themselves (trained and chosen on the very frames
   it is measured on). The **safe ceiling** (:data:`SAFE_CEILING_ARGS`) keeps tune's safety sweep and gate: the
   best file tune would write had it been given the held-out frames, so the gap tune should close. The
   **fitness bound** (:data:`CEILING_ARGS`) is chosen by the fitness alone, no safety sweep, written whatever
   the gate says: the most the search could give, safe or not. Either is the base when its tune does not beat
   the base there (the search found no room: :func:`ceiling_params`);
5. every file ranged on the held-out frames as the daemon flies it (flight pipeline, then its ranging stage):
   median absolute branch-distance error, the worst reading farther than the truth, frames farther than 2 %,
   frames with no measurement, and ms per frame, timed side by side in this process.

The written file is the tuned one, or the base when tune refused (the refusal is printed, and the rejected
candidate measured too: a refusal is right when the candidate would not have ranged the held-out frames better).
Per rig: how much of the base-to-safe-ceiling gap (median error) the written file closes. A refusal where the
safe ceiling is the base is right by construction: no file tune may write beats the base even in-sample.

``--metric selfsup`` tunes without the reference disparity; ``--logs daemon`` tunes on what the daemon itself
logs (``uav-depth run`` on the synthetic source at the rig, frame logging on; references and truth removed, as
a real flight logs them) instead of synthetic sessions written directly. The held-out sessions are the same.

    nice python bench/new_rig.py --work /tmp/new-rig [--rigs oak-d,zed-1080,cheap] [--seeds 0,1,2]
                                 [--population 30 --generations 100] [--metric selfsup] [--logs daemon]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from new_rig_logs import daemon_logs

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.params import load_params
from uav_depth.core.session import SessionWriter, iter_frames
from uav_depth.sim.scene import Scene
from uav_depth.sim.scene_config import SceneConfig, vary
from uav_depth.tuning.frames import FrameSet, load_frame
from uav_depth.tuning.front import time_params
from uav_depth.tuning.metrics import FARTHER_TOL_PCT, branch_signed
from uav_depth.tuning.objective import FITNESS, branch_distances

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
#: The shipped files and the image width each was made for.
SHIPPED = {1280: DEPLOY / "params-flight.yaml", 640: DEPLOY / "params-flight-640x360.yaml"}


@dataclass(frozen=True)
class Rig:
    name: str
    width: int
    height: int
    focal_px: float
    baseline_m: float
    #: Scene keys every frame of the rig keeps (its camera's flaws), over what ``vary`` draws.
    camera: dict = field(default_factory=dict)

    def scene(self) -> SceneConfig:
        return SceneConfig(width=self.width, height=self.height, focal_px=self.focal_px, baseline_m=self.baseline_m)

    def base_file(self) -> Path:
        """The nearest shipped file: the one made for the closest image width."""
        return SHIPPED[min(SHIPPED, key=lambda w: abs(w - self.width))]


RIGS = {
    # OAK-D (OV9282 pair): 1280x800, about 72 degrees across, 75 mm baseline
    "oak-d": Rig("oak-d", 1280, 800, 880.0, 0.075),
    # ZED Mini at HD1080: 1920x1080, 63 mm baseline
    "zed-1080": Rig("zed-1080", 1920, 1080, 1050.0, 0.063),
    # a cheaper VGA pair: more noise, the right eye 12 % brighter with a black level 6 higher, both eyes blurred
    "cheap": Rig("cheap", 640, 480, 500.0, 0.06, {"noise_std": 6.0, "right_gain": 1.12, "right_offset": 6.0,
                                                  "blur_sigma": 1.2, "right_blur_sigma": 0.6}),
}


def write_session(path: Path, rig: Rig, seed: int, frames: int) -> Path:
    """One synthetic session at ``rig``: scenes drawn from (seed, i), every other one leafy, the rig's camera
    flaws kept; exact reference disparity, branch mask and truth per frame (skipped when already written)."""
    if (path / "frames" / f"{frames - 1:06d}_left.png").exists():
        return path
    writer = SessionWriter(path, rig.scene().calibration)
    for i in range(frames):
        rng = np.random.default_rng([seed, i])
        cfg = vary(rig.scene(), rng, leafy=i % 2 == 1, **rig.camera)
        frame = Scene(cfg).render(rng=rng)
        roi = cfg.center_roi
        writer.write(i, frame.left, frame.right, reference=frame.disparity,
                     meta={"branch_distance_m": frame.nearest_branch_distance(roi), "roi": list(roi),
                           "scene": cfg.to_dict()},
                     reference_source={"kind": "synthetic", "exact": True, "note": "bench/new_rig.py"})
        np.save(writer.session.frames_dir / f"{i:06d}_branch.npy", frame.branch_mask)
    return path


def sessions(root: Path, rig: Rig, seeds: list[int], frames: int) -> Path:
    for seed in seeds:
        write_session(root / f"s{seed:03d}", rig, seed, frames)
    return root


@dataclass
class Measured:
    """One parameter file ranged on the held-out frames as the daemon flies it."""

    median_pct: float
    worst_farther_pct: float
    farther: int
    none: int
    frames: int
    ms: float

    def row(self) -> str:
        return (f"{self.median_pct:6.2f} | {self.worst_farther_pct:+7.2f} | {self.farther:3d} | {self.none:3d} | "
                f"{self.ms:7.1f}")


def measure(params, held: FrameSet) -> Measured:
    """Median |error| %, the farthest reading's error % (nearer readings are the safe side: 0 when none is
    farther), frames farther than 2 %, frames without a distance, ms per frame (in this process)."""
    errors = [branch_signed(d, f.branch_distance_m) for d, f in zip(branch_distances(params, held), held.frames)]
    read = [e for e in errors if np.isfinite(e)]
    return Measured(float(np.median(np.abs(read))) if read else float("nan"), max([0.0] + read),
                    sum(e > FARTHER_TOL_PCT for e in read), len(errors) - len(read), len(errors),
                    time_params(params, held))


def run_tune(logdir: Path, base: Path, out: Path, seed: int, args, extra: list[str]) -> dict:
    """``uav-depth tune`` as a user runs it; its exit status, one-line refusal and wall time."""
    cmd = [sys.executable, "-m", "uav_depth.cli.main", "tune", str(logdir), "--base", str(base), "--out", str(out),
           "--seed", str(seed), "--report", str(out.with_suffix("")) + "-report", "--no-progress"]
    for opt in ("population", "generations", "workers", "metric"):
        if getattr(args, opt) is not None:
            cmd += [f"--{opt}", str(getattr(args, opt))]
    cmd += args.tune_args + extra           # the ceiling's own arguments last: they win
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    refused = next((line.split("not written: ", 1)[1] for line in proc.stderr.splitlines() if "not written: " in line),
                   None)
    if proc.returncode not in (0, 1) or (proc.returncode == 1 and refused is None):
        raise SystemExit(f"tune failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return {"rc": proc.returncode, "refused": refused, "wall_s": time.monotonic() - t0,
            "line": next((line for line in proc.stdout.splitlines() if " candidates: " in line), "")}


#: The fitness bound: trained and chosen on the held-out frames themselves, on the fitness alone (no safety
#: sweep: an accuracy bound to compare with, not a file to fly), written whatever the gate says.
CEILING_ARGS = ["--test", "none", "--holdout", "none", "--safety-sweep", "none", "--force"]
#: The safe ceiling: the same, with tune's own safety sweep (that of ``--tune-args``) and gate, not forced: what
#: tune would write had it been given the held-out frames. A gain the sweep refuses even there is not room a
#: tune may take (on the noisy rig, 30 candidates that beat the base on the held-out frames read more of the
#: sweep's frames farther than it).
SAFE_CEILING_ARGS = ["--test", "none", "--holdout", "none"]


def ceiling_params(ceiling_file: Path, base, metric: str | None):
    """The ceiling tune's file when it beat the base on its own fitness on the frames it was tuned on (its
    provenance: ``judged_fitness`` against ``judged_baseline_fitness``), else the base (also when tune wrote
    nothing); and whether it beat it."""
    if not ceiling_file.exists():
        return base, {"beat_base": False, "fitness": float("nan"), "base_fitness": float("nan")}
    text = yaml.safe_load(ceiling_file.read_text())["provenance"]
    fitness = FITNESS[text["metric"] if metric is None else metric]
    beat = fitness.utility(text["judged_fitness"]) > fitness.utility(text["judged_baseline_fitness"])
    return (load_params(ceiling_file) if beat else base), {"beat_base": beat, "fitness": text["judged_fitness"],
                                                           "base_fitness": text["judged_baseline_fitness"]}


def one_seed(rig: Rig, train: Path, held_dir: Path, held: FrameSet, seed: int, work: Path, args) -> dict:
    """The base, the tuned (written or rejected) and the ceiling file of one tune seed, measured held out."""
    base_file = rig.base_file()
    base = load_params(base_file)
    out = work / f"tuned-s{seed}.yaml"
    for stale in (out, work / f"tuned-s{seed}.rejected.yaml"):
        stale.unlink(missing_ok=True)
    tuned = run_tune(train, base_file, out, seed, args, [])
    ceiling_file = work / f"ceiling-s{seed}.yaml"
    ceiling = run_tune(held_dir, base_file, ceiling_file, seed, args, CEILING_ARGS)
    safe_file = work / f"safe-ceiling-s{seed}.yaml"
    safe_file.unlink(missing_ok=True)
    safe = run_tune(held_dir, base_file, safe_file, seed, args, SAFE_CEILING_ARGS)
    rejected = work / f"tuned-s{seed}.rejected.yaml"
    written = load_params(out) if out.exists() else base
    ceiling_p, ceiling["fitness"] = ceiling_params(ceiling_file, base, args.metric)
    safe_p, safe["fitness"] = ceiling_params(safe_file, base, args.metric)
    result = {"seed": seed, "tune": tuned, "ceiling_tune": ceiling, "safe_ceiling_tune": safe,
              "base": measure(base, held).__dict__, "written": measure(written, held).__dict__,
              "safe_ceiling": measure(safe_p, held).__dict__, "ceiling": measure(ceiling_p, held).__dict__}
    if rejected.exists() and load_params(rejected) != base:      # the choice kept the base: nothing to judge
        result["rejected"] = measure(load_params(rejected), held).__dict__
    return result


def verdict(r: dict) -> str:
    """Whether the seed met the goal: the written file ranges the held-out frames better (median) with no more
    frames farther than 2 %, or tune refused (and whether the refusal was right)."""
    b, w = r["base"], r["written"]
    if r["tune"]["refused"] is not None:
        rej = r.get("rejected")
        if not r["safe_ceiling_tune"]["fitness"]["beat_base"]:
            return "refused, rightly: the safe ceiling is the base (no file tune may write beats it, even in-sample)"
        if rej is None:
            return "refused: no candidate beat the base where the choice was made"
        right = not (rej["median_pct"] < b["median_pct"] and rej["farther"] <= b["farther"])
        return f"refused ({'rightly' if right else 'WRONGLY: the candidate ranged better'})"
    if w["median_pct"] < b["median_pct"] and w["farther"] <= b["farther"]:
        return "better"
    return "WRITTEN BUT NOT BETTER"


def gap_closed(r: dict) -> float:
    """Share of the base-to-safe-ceiling gap in median error the written file closes (NaN: no gap)."""
    b, w, c = r["base"]["median_pct"], r["written"]["median_pct"], r["safe_ceiling"]["median_pct"]
    return (b - w) / (b - c) if b - c > 1e-9 else float("nan")


def print_rig(rig: Rig, results: list[dict], held: FrameSet) -> None:
    print(f"\n{rig.name}: {rig.width}x{rig.height}, f {rig.focal_px:g} px, B {rig.baseline_m:g} m, "
          f"{rig.camera or 'clean camera'}; base {rig.base_file().relative_to(DEPLOY.parent)}; "
          f"{len(held)} held-out frames")
    print("seed | file         | median |err| % | worst farther % | > 2 % farther | no measurement | ms/frame | ")
    for r in results:
        for name in ("base", "written", "rejected", "safe_ceiling", "ceiling"):
            if name in r:
                m = Measured(**r[name])
                label = {"safe_ceiling": "safe ceiling", "ceiling": "bound"}.get(name, name)
                print(f"{r['seed']:4d} | {label:12s} | {m.row()} |")
        for name, key in (("safe ceiling", "safe_ceiling_tune"), ("bound", "ceiling_tune")):
            fit = r[key]["fitness"]
            said = (f"its tune's file: fitness {fit['fitness']:.4g} against the base's {fit['base_fitness']:.4g}"
                    if fit["beat_base"] else f"the base ({r[key]['refused'] or 'its tune did not beat it'})")
            print(f"     {name} on the held-out frames: {said}")
        tune = r["tune"]
        gap = gap_closed(r)
        print(f"     tune: {verdict(r)}; {'no gap' if math.isnan(gap) else f'gap closed {gap:.0%}'}; "
              f"{tune['wall_s']:.0f} s; "
              f"{tune['refused'] or 'written'}\n     {tune['line']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="/tmp/new-rig", help="sessions, files and reports (kept and reused)")
    ap.add_argument("--rigs", default=",".join(RIGS), help=f"comma list of {', '.join(RIGS)}")
    ap.add_argument("--seeds", default="0,1,2", help="tune seeds (--seed)")
    ap.add_argument("--train-seeds", type=int, default=4, help="training sessions (scene seeds 0..N-1)")
    ap.add_argument("--held-seeds", type=int, default=4, help="held-out sessions (scene seeds 100..)")
    ap.add_argument("--frames", type=int, default=4, help="frames per session")
    ap.add_argument("--population", type=int, default=None, help="tune's --population (default: tune's own)")
    ap.add_argument("--generations", type=int, default=None, help="tune's --generations (default: tune's own)")
    ap.add_argument("--workers", type=int, default=None, help="tune's --workers")
    ap.add_argument("--metric", default=None, help="tune's --metric (selfsup: no reference)")
    ap.add_argument("--tune-args", default="", type=lambda t: t.split(),
                    help="more tune arguments for every tune, e.g. '--safety-sweep quick' (say so when you report)")
    ap.add_argument("--logs", choices=("synthetic", "daemon"), default="synthetic",
                    help="train on synthetic sessions, or on the daemon's own frame log of the synthetic source")
    ap.add_argument("--json", default=None, help="write every figure here")
    ap.add_argument("--label", default="", help="names this run's folder of files and reports (runs side by side)")
    args = ap.parse_args()
    print(machine_line())
    print(f"load: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1/5/15 min); {' '.join(sys.argv[1:])}")
    out = {}
    for name in args.rigs.split(","):
        rig, work = RIGS[name], Path(args.work) / name
        held_dir = sessions(work / "held", rig, list(range(100, 100 + args.held_seeds)), args.frames)
        if args.logs == "daemon":
            train = daemon_logs(work / "daemon-logs", rig, list(range(args.train_seeds)), args.frames)
        else:
            train = sessions(work / "train", rig, list(range(args.train_seeds)), args.frames)
        held = FrameSet("held", tuple(load_frame(r) for r in iter_frames(held_dir)))
        label = [args.metric or "default", args.logs] + [a.strip("-") for a in args.tune_args] + [args.label]
        runs = work / ("runs-" + "-".join(filter(None, label)))
        runs.mkdir(parents=True, exist_ok=True)
        results = [one_seed(rig, train, held_dir, held, int(s), runs, args) for s in args.seeds.split(",")]
        print_rig(rig, results, held)
        out[name] = results
    print(f"\nload: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1/5/15 min)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
