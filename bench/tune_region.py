"""Where the flown fitness should score the map: the ranging region alone, or everything the candidate matches.

Middlebury 2006 (17 real scenes, dense ground truth), the split of ``bench/tune_real.py`` (tune on 6, report
on 11). For each seed, Optuna's TPE (multivariate, the base enqueued first, as ``uav-depth tune`` asks it) runs
``--trials`` proposals of the flown keys on the 6 training scenes twice:

- ``ranging``: the map scored in the ranging region alone (the daemon's default, the central third), plus the
  branch term (the other way the flown fitness could score the map);
- ``matched``: the map scored over the matched region (``tuning.objective.FITNESS["flown"]`` as it is now),
  plus the same branch term.

Each winner (best training value, no held-out choice: this isolates the score's region) is reported on the 11
held-out scenes against the manual baseline: mean absolute error in the ranging region and over the whole
frame, bad-2 over the whole frame, and the scenes more than 5 % worse on whole-frame MAE.

    nice python bench/tune_region.py --data DIR/middlebury2006 [--seeds 0 1 2] [--trials 160]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tune_real  # noqa: E402  (the sessions and the split)


from uav_depth.cli.benchmark import machine_line  # noqa: E402
from uav_depth.core.disparity import flight_pipeline  # noqa: E402
from uav_depth.core.params import DEFAULT_PARAMS  # noqa: E402
from uav_depth.core.session import iter_frames  # noqa: E402
from uav_depth.core.ranging import resolve_roi  # noqa: E402
from uav_depth.tuning.frames import load_frame  # noqa: E402
from uav_depth.tuning.objective import BRANCH_PX_PER_PCT, _branch, bench, flown_map, scored_box  # noqa: E402
from uav_depth.tuning.space import FLOWN_KEYS, SchemaSpace, build  # noqa: E402


def scene(f) -> str:
    return f.key.split("/")[0]


def region_box(f):
    h, w = f.left.shape[:2]
    return resolve_roi(f.roi, w, h)


def scores(params, on):
    """Per frame of ``on``: (ranging-region MAE, whole-frame MAE, whole-frame bad-2, branch term), or None
    when the candidate fails (a warning, or no measured pixel)."""
    pipeline = flight_pipeline(params)
    out = {}
    for f in on:
        res = pipeline.run(f.left, f.right)
        if res.warning is not None or not np.isfinite(res.measured).any():
            return None
        m = flown_map(res)
        whole = bench(f, m, scored_box(params, f.left.shape))
        out[f.key] = (bench(f, m, region_box(f))["mae"], whole["mae"], whole["bad2"],
                      BRANCH_PX_PER_PCT * _branch(f, res, params) if f.has_branch else 0.0)
    return out


def fitness(region: str, params, train) -> float:
    """The flown fitness on the training scenes, the map scored in ``region``: "matched" is ``FITNESS["flown"]``
    as it is now (whole-frame MAE + branch term; tests/tuning/test_study.py checks that sum), "ranging" the
    map scored in the ranging region alone."""
    got = scores(params, train)
    if got is None:
        return float("inf")
    return float(np.mean([v[0 if region == "ranging" else 1] + v[3] for v in got.values()]))


def search(space, region: str, seed: int, trials: int, train):
    """TPE over ``space`` from the manual baseline, ``trials`` proposals: the best parameters."""
    import optuna

    names = [f"g{i}" for i in range(space.size)]
    study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=seed, multivariate=True))
    study.enqueue_trial(dict(zip(names, map(float, space.encode(DEFAULT_PARAMS)))))
    dist = {k: optuna.distributions.FloatDistribution(0.0, 1.0) for k in names}
    for _ in range(trials):
        trial = study.ask(dist)
        try:
            value = fitness(region, build(space, [trial.params[k] for k in names], DEFAULT_PARAMS), train)
        except Exception:  # noqa: BLE001  (a candidate the schema refuses is a failed trial)
            value = float("inf")
        study.tell(trial, value if np.isfinite(value) else 1e9)
    return build(space, [study.best_trial.params[k] for k in names], DEFAULT_PARAMS)


def row(seed: int, region: str, best, base: dict, train, test, seconds: float) -> str:
    got = scores(best, train + test)

    def change(on, i):
        b = np.mean([base[f.key][i] for f in on])
        return (np.mean([got[f.key][i] for f in on]) - b) / b * 100.0

    worse = [scene(f) for f in test if (got[f.key][1] - base[f.key][1]) / base[f.key][1] > 0.05]
    sg = best.sgbm
    return (f"| {seed} | {region} | {change(train, 0):+.1f} % | {change(test, 0):+.1f} % | {change(test, 1):+.1f} % "
            f"| {change(test, 2):+.1f} % | {len(worse)} ({', '.join(worse) or '-'}) | block {sg.block_size}, P1 "
            f"{sg.p1}, P2 {sg.p2}, uniqueness {sg.uniqueness_ratio}, disp12 {sg.disp12_max_diff} | {seconds:.0f} |")


def main() -> int:
    import optuna

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the middlebury2006 folder (17 scene folders)")
    ap.add_argument("--work", default=None, help="where the sessions go (default: a temporary folder)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--trials", type=int, default=160)
    args = ap.parse_args()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="tune_region_"))
    tune_real.make_sessions(Path(args.data), work)
    frames = [load_frame(r) for r in iter_frames(work / "sessions", require_reference=True)]
    train = [f for f in frames if scene(f) in tune_real.TRAIN]
    test = [f for f in frames if scene(f) not in tune_real.TRAIN]
    print(machine_line())
    print(f"train: {', '.join(sorted(tune_real.TRAIN))}; held out: {', '.join(sorted(scene(f) for f in test))}; "
          f"TPE {args.trials} proposals per run; map scored in the ranging region (central third) or over the "
          "matched region (whole frame here)")
    base = scores(DEFAULT_PARAMS, frames)
    space = SchemaSpace(FLOWN_KEYS)
    print("\n| seed | map scored | train MAE, ranging region | held-out MAE, ranging region | held-out MAE, whole "
          "| held-out bad-2, whole | held-out scenes > 5 % worse (whole MAE) | chosen sgbm | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        for region in ("ranging", "matched"):
            t0 = time.perf_counter()
            best = search(space, region, seed, args.trials, train)
            print(row(seed, region, best, base, train, test, time.perf_counter() - t0), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
