"""Faithful vs improved search at an equal budget: tuned vs the base on train and held-out frames.

Runs each optimiser (same metric, population x generations, runs, seed) on the
same frames and prints, per optimiser, the fitness of its best parameters and
the change of MSE, PSNR, SSIM, bad-2 (and branch error where known) against the
base (`--base`, by default the manual baseline) on the training and the held-out frames, next to the paper's
-42.86% MSE / +8.47% PSNR / +28.52% SSIM.

    python bench/tuner_compare.py --data motorcycle --generations 20
    uav-depth synth /tmp/syn --frames 8 --width 640 --height 360 --focal-px 350 --seed 1
    python bench/tuner_compare.py --data /tmp/syn --holdout 0.5 --generations 20

``--json FILE`` also writes every number.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np


def load(data: str, holdout: str | None, needs):
    from uav_depth.tuning.frames import FrameSet
    from uav_depth.tuning.split import load_split

    if data == "motorcycle":
        import importlib.util
        import sys
        from pathlib import Path

        spec = importlib.util.spec_from_file_location("tuner_bench", Path(__file__).with_name("tuner_bench.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules["tuner_bench"] = mod
        spec.loader.exec_module(mod)
        return mod.motorcycle(), FrameSet("holdout", ())
    return load_split(data, holdout, needs)


def main() -> int:
    from uav_depth.core.params import DEFAULT_PARAMS, load_params, params_from_dict
    from uav_depth.tuning.executor import make_executor
    from uav_depth.tuning.objective import FITNESS
    from uav_depth.tuning.report import PAPER_CHANGE, comparison
    from uav_depth.tuning.store import RunStore
    from uav_depth.tuning.choice import full_scores
    from uav_depth.tuning.study import Study, StudyConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="motorcycle", help="'motorcycle' or a log directory")
    ap.add_argument("--holdout", default=None)
    ap.add_argument("--metric", default="mse")
    ap.add_argument("--optimizers", nargs="+", default=["ga-paper", "ga", "random", "tpe"])
    ap.add_argument("--population", type=int, default=30)
    ap.add_argument("--generations", type=int, default=20)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keys", default=None)
    ap.add_argument("--base", default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    from uav_depth.tuning.space import parse_keys

    fitness = FITNESS[args.metric]
    base = load_params(args.base) if args.base else DEFAULT_PARAMS
    train, held = load(args.data, args.holdout, fitness.needs)
    sets = {"train": train, "holdout": held}
    names = [n for n in ("train", "holdout") if len(sets[n])]
    print(f"data {args.data}: {len(train)} train, {len(held)} held-out frame(s); metric {args.metric}; "
          f"budget {args.population} x {args.generations} x {args.runs} run(s), seed {args.seed}")
    out = {"args": vars(args), "results": {}}
    with make_executor(sets, args.metric, args.workers) as ex:
        for opt in args.optimizers:
            config = StudyConfig(metric=args.metric, optimizer=opt, population=args.population,
                                 generations=args.generations, runs=args.runs, seed=args.seed,
                                 keys=parse_keys(args.keys))
            t0 = time.perf_counter()
            study = Study(config, train, ex, RunStore(), base)
            res = study.run()
            wall = time.perf_counter() - t0
            bests = [r.best_value for r in res.runs]
            run_params = [params_from_dict(r.best_params) for r in res.runs if r.best_params is not None]
            scores = full_scores(ex, [base, *run_params], names)
            best_i = 1 + [r.run for r in res.runs if r.best_params is not None].index(res.best.run)
            cmp = comparison({n: scores[(0, n)] for n in names}, {n: scores[(best_i, n)] for n in names})
            # every run's best on every frame set: the spread says how much one run can be trusted
            per_run = {n: [comparison({n: scores[(0, n)]}, {n: scores[(i, n)]})[n]["metrics"]
                           for i in range(1, len(run_params) + 1)] for n in names}
            out["results"][opt] = {"best_per_run": bests, "baseline": res.baseline.value, "comparison": cmp,
                                   "per_run": per_run, "evaluated": res.evaluated, "cached": res.cached,
                                   "wall_s": wall, "best_params": res.best_params().to_dict(),
                                   "history_mean": np.nanmean([r.history for r in res.runs], axis=0).tolist()}
            spread = f" (runs: mean {np.mean(bests):.4g} +- {np.std(bests):.2g})" if args.runs > 1 else ""
            print(f"\n{opt}: best {args.metric} {res.best.best_value:.4g} vs base {res.baseline.value:.4g}{spread}; "
                  f"{res.evaluated} evaluated, {res.cached} cached, {wall:.0f} s")
            for n in names:
                cells = []
                for m in ("mse", "psnr", "ssim", "bad2", "branch"):
                    row = cmp[n]["metrics"].get(m)
                    if row:
                        paper = f" [paper {PAPER_CHANGE[m]:+.2f}%]" if m in PAPER_CHANGE else ""
                        cells.append(f"{m} {row['base']:.4g}->{row['tuned']:.4g} ({row['change_pct']:+.1f}%){paper}")
                print(f"  {n:<8}" + "; ".join(cells))
                if len(run_params) > 1:
                    ch = [r[args.metric]["change_pct"] for r in per_run[n] if args.metric in r]
                    print(f"  {'':<8}{args.metric} change of each run's best: mean {np.mean(ch):+.1f}% +- "
                          f"{np.std(ch):.1f} ({', '.join(f'{c:+.1f}' for c in ch)})")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=lambda o: None if isinstance(o, float) and not math.isfinite(o)
                      else str(o))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
