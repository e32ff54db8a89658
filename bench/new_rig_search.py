"""Where tune's search finds room on a new rig: the search space around the base against the whole of it, and
TPE's start, on ``bench/new_rig.py``'s sessions (run that first; it writes them under ``--work``).

1. ``space``: ``--samples`` uniform genomes of the improved space and as many neighbours of the base (sd
   ``GA_LOCAL_SIGMA``), each scored (flown) on the training sessions s000-s002, on tune's test session s003 and
   on the held-out sessions: how many fail, how many beat the base on the training frames, whether those beat it
   held out too, and how the training and held-out figures correlate (does the fitness carry over?).
2. ``start``: the fold searches of ``tune`` (each fold's training sessions, ``--budget`` per fold) with TPE as
   shipped (its whole first generation the base and neighbours, those its startup) and with Optuna's default
   start (the base and a third of a generation of neighbours, then 10 uniform startup draws): per seed, the
   failed proposals, those better than the base on the fold's training frames, and the best one's figures on
   the fold's validation session and held out.
3. ``safe``: is there a file both better and safe at all? TPE as shipped (the same start) on the held-out
   sessions, the ceiling's frames, but told the safety sweep while it searches: each proposal is also read on
   the rendered sweep (``--sweep``, an entry of tune's ``--sweep-cache``) and is feasible only when it reads no
   more frames farther than the truth by more than 2 % than the base does (Optuna's trial constraints). It
   searches on the very frames it is judged on, so it answers whether such a file exists, not what tune
   would find: per seed, the feasible proposals better than the base and the best one's held-out figures.

    nice python bench/new_rig_search.py --work /tmp/new-rig --rig cheap space --samples 60
    nice python bench/new_rig_search.py --work /tmp/new-rig --rig cheap start --budget 8x4 --seeds 0,1,2,3,4,5
    nice python bench/new_rig_search.py --work /tmp/new-rig --rig cheap safe --budget 16x8 --seeds 0 \
        --sweep ~/.cache/uav-depth/safety-sweep/standard-640x480-...
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from new_rig import RIGS, measure
from store_on_sweep import farther

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.params import load_params
from uav_depth.core.session import iter_frames
from uav_depth.tuning import optimizers
from uav_depth.tuning.executor import SerialExecutor
from uav_depth.tuning.frames import FrameSet, load_frame
from uav_depth.tuning.objective import FITNESS, evaluate
from uav_depth.tuning.space import FLOWN_KEYS, SchemaSpace
from uav_depth.tuning.store import RunStore
from uav_depth.tuning.study import Study, StudyConfig

FLOWN = FITNESS["flown"]
#: tune's split of new_rig.py's four training sessions: the last is the test, three folds over the others.
FOLDS = ((("s001", "s002"), "s000"), (("s000", "s002"), "s001"), (("s000", "s001"), "s002"))


def frames(root: Path, names) -> FrameSet:
    return FrameSet("train", tuple(load_frame(r) for n in names for r in iter_frames(root / n)))


def score(params, fs: FrameSet) -> float | None:
    ev = evaluate(params, fs, FLOWN)
    return ev.value if ev.ok else None


def space_map(work: Path, base, n: int) -> None:
    train = frames(work / "train", ("s000", "s001", "s002"))
    test = frames(work / "train", ("s003",))
    held = frames(work / "held", sorted(p.name for p in (work / "held").iterdir()))
    space, rng = SchemaSpace(FLOWN_KEYS), np.random.default_rng(7)
    start = space.encode(base)
    b = [score(base, s) for s in (train, test, held)]
    print(f"base: train {b[0]:.2f}, test {b[1]:.2f}, held out {b[2]:.2f} (flown, lower is better)")
    sd = optimizers.GA_LOCAL_SIGMA
    draws = {"uniform": lambda: rng.random(start.size),
             f"neighbours sd {sd:g}": lambda: np.clip(start + rng.normal(0, sd, start.size), 0, 1),
             f"neighbours sd {2 * sd:g}": lambda: np.clip(start + rng.normal(0, 2 * sd, start.size), 0, 1)}
    rows: dict[str, list] = {name: [] for name in draws}
    for _ in range(n):                      # interleaved: one of each kind in turn, from one generator
        for name, draw in draws.items():
            p = base.replace(**space.decode(draw(), base))
            rows[name].append(([score(p, s) for s in (train, test, held)], p.sgbm.block_size))
    for name, got in rows.items():
        ok = [(v, bs) for v, bs in got if None not in v]
        better = [(v, bs) for v, bs in ok if v[0] < b[0]]
        corr = np.corrcoef([v[0] for v, _ in ok], [v[2] for v, _ in ok])[0, 1] if len(ok) > 2 else math.nan
        print(f"{name}: {n} drawn, {n - len(ok)} failed, {len(better)} better than the base on the training "
              f"frames, of those {sum(v[1] < b[1] for v, _ in better)} on the test session and "
              f"{sum(v[2] < b[2] for v, _ in better)} held out; their block sizes {sorted(bs for _, bs in better)}; "
              f"train/held-out correlation {corr:.2f}")


def optuna_default_start(space, population, rng, base):
    """TPE with Optuna's default start: the base and a third of a generation of neighbours enqueued, then 10
    uniform startup draws before its model begins."""
    import optuna

    opt = optimizers.TPESearch.__new__(optimizers.TPESearch)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    opt._fail = optuna.trial.TrialState.FAIL
    start = optimizers.local_start(space, population, rng, base)     # drawn first, as the shipped TPE does
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        sampler = optuna.samplers.TPESampler(seed=int(rng.integers(0, 2**31 - 1)), multivariate=True)
    opt.study = optuna.create_study(direction="maximize", sampler=sampler)
    opt.names = [f"g{i:02d}" for i in range(space.size)]
    for genome in start:
        opt.study.enqueue_trial(dict(zip(opt.names, map(float, genome))))
    opt.n, opt.trials = population, []
    return opt


def start_compare(work: Path, base, budget: str, seeds: list[int]) -> None:
    pop, gens = (int(x) for x in budget.split("x"))
    held = frames(work / "held", sorted(p.name for p in (work / "held").iterdir()))
    shipped = optimizers.OPTIMIZERS["tpe"]
    starts = {"shipped": shipped, "optuna-default-start": optimizers.OptimizerSpec(
        "tpe", "schema", optuna_default_start, "TPE with Optuna's default start")}
    for j, (train_names, val_name) in enumerate(FOLDS):
        train, val = frames(work / "train", train_names), frames(work / "train", (val_name,))
        bt, bv, bh = score(base, train), score(base, val), score(base, held)
        print(f"fold {j + 1} (train {'+'.join(train_names)}, validation {val_name}): base {bt:.2f}, "
              f"validation {bv:.2f}, held out {bh:.2f}")
        executor = SerialExecutor({"train": train}, "flown")
        for name, spec in starts.items():
            optimizers.OPTIMIZERS["tpe"] = spec
            for seed in seeds:
                store = RunStore(":memory:", "minimize", list(FLOWN_KEYS))
                study = Study(StudyConfig(population=pop, generations=gens, seed=seed, keys=FLOWN_KEYS), train,
                              executor, store, base)
                study.open(False)
                result = study.run()
                evs = [ev for _, _, ev in store.evaluations()]
                best = result.best_params()
                print(f"  {name:21s} seed {seed}: {sum(not e.ok for e in evs):2d} failed, "
                      f"{sum(e.ok and e.value < bt for e in evs):2d} better than the base; best: train "
                      f"{result.best.best_value:.2f}, validation {score(best, val):.2f}, held out "
                      f"{score(best, held):.2f}, block size {best.sgbm.block_size}", flush=True)
        optimizers.OPTIMIZERS["tpe"] = shipped
        executor.close()


def safe_search(work: Path, base, budget: str, seeds: list[int], sweep_dir: str) -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    pop, gens = (int(x) for x in budget.split("x"))
    held = frames(work / "held", sorted(p.name for p in (work / "held").iterdir()))
    sweep = FrameSet("sweep", tuple(load_frame(r) for r in iter_frames(sweep_dir)))
    bh, nb = score(base, held), farther(base, sweep)
    mb = measure(base, held)
    print(f"base: held out {bh:.2f} (flown), {nb} of {len(sweep)} sweep frames farther; held-out median "
          f"{mb.median_pct:.2f} %, {mb.farther} farther, {mb.none} unmeasured")
    space = SchemaSpace(FLOWN_KEYS)
    names = [f"g{i:02d}" for i in range(space.size)]
    for seed in seeds:
        rng = np.random.default_rng(seed)
        start = optimizers.local_start(space, pop, rng, base, optimizers.TPE_LOCAL_FRACTION)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            sampler = optuna.samplers.TPESampler(seed=seed, multivariate=True, n_startup_trials=len(start))
        study = optuna.create_study(direction="minimize", sampler=sampler)
        for genome in start:
            study.enqueue_trial(dict(zip(names, map(float, genome))))
        found: dict = {}

        def objective(trial):
            params = base.replace(**space.decode([trial.suggest_float(n, 0.0, 1.0) for n in names], base))
            value = score(params, held)
            over = math.inf if value is None else farther(params, sweep) - nb    # a failed one is infeasible
            trial.set_constraint("over", over)         # feasible at <= 0: TPE models the infeasible apart
            found[trial.number] = params
            return math.inf if value is None else value

        t0 = time.monotonic()
        study.optimize(objective, n_trials=pop * gens)
        ok = [t for t in study.trials if t.value is not None and math.isfinite(t.value)]
        better = [t for t in ok if t.value < bh]
        safe = [t for t in better if t.constraints["over"] <= 0]
        line = (f"seed {seed}: {len(study.trials)} proposals ({time.monotonic() - t0:.0f} s), "
                f"{len(study.trials) - len(ok)} failed, {len(better)} better than the base held out, "
                f"{len(safe)} of them reading no more sweep frames farther")
        measured = sorted(((t.value, t, measure(found[t.number], held)) for t in safe), key=lambda r: r[0])
        goal = [r for r in measured if r[2].median_pct < mb.median_pct and r[2].farther <= mb.farther]
        line += f"; {len(goal)} of those range the held-out frames better with no more of them farther"
        for what, rows in (("the best", measured[:1]), ("the best of those", goal[:1])):
            for value, t, m in rows:
                line += (f"; {what}: {value:.2f} (flown), {nb + int(t.constraints['over'])} sweep frames farther, "
                         f"held-out median {m.median_pct:.2f} %, {m.farther} farther, {m.none} unmeasured")
        print(line, flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("space", "start", "safe"))
    ap.add_argument("--work", default="/tmp/new-rig", help="bench/new_rig.py's --work")
    ap.add_argument("--rig", default="cheap", choices=list(RIGS))
    ap.add_argument("--samples", type=int, default=60, help="space: genomes of each kind")
    ap.add_argument("--budget", default="8x4", help="start: POPULATIONxGENERATIONS per fold; safe: the search's")
    ap.add_argument("--seeds", default="0,1,2,3,4,5", help="start, safe: tune seeds")
    ap.add_argument("--sweep", help="safe: the rendered sweep at the rig (an entry of tune's --sweep-cache)")
    args = ap.parse_args()
    print(machine_line())
    work, base = Path(args.work) / args.rig, load_params(RIGS[args.rig].base_file())
    if args.what == "space":
        space_map(work, base, args.samples)
    elif args.what == "safe":
        if not args.sweep:
            ap.error("safe needs --sweep")
        safe_search(work, base, args.budget, [int(s) for s in args.seeds.split(",")], args.sweep)
    else:
        start_compare(work, base, args.budget, [int(s) for s in args.seeds.split(",")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
