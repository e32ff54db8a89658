"""Is there safe room below the candidates a tune's choice looked at?

Tune's choice reads the safety sweep only for its best few candidates. This reads every ``--stride``-th of all
the proposals in a tune's run store that beat the base on the fitness (by rank) on the whole rendered sweep,
as the gate reads it (``branch_distances``: the flight pipeline, then its ranging stage), and counts the frames
read farther than the truth by more than 2 % (the sweep's first rule), the base's beside them. A proposal that
reads no more than the base is one a choice that looked further could have written::

    nice python bench/store_on_sweep.py REPORT/store.sqlite ~/.cache/uav-depth/safety-sweep/standard-1280x800-... \\
        --base deploy/params-flight.yaml --base-value 12.41 --stride 10
"""

from __future__ import annotations

import argparse
import json
import math
import time

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.params import load_params, params_from_dict
from uav_depth.core.session import iter_frames
from uav_depth.tuning.frames import FrameSet, load_frame
from uav_depth.tuning.metrics import is_farther
from uav_depth.tuning.objective import FITNESS, branch_distances


def better_than_base(store: str, base_value: float, metric: str) -> list[tuple[dict, float]]:
    """Distinct parameter sets of the store's first study that beat ``base_value``, best first."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    url = f"sqlite:///{store}"
    study = optuna.load_study(study_name=optuna.get_all_study_names(url)[0], storage=url)
    utility = FITNESS[metric].utility
    rows: dict[str, float] = {}
    for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)):
        if t.value is not None and utility(t.value) > utility(base_value):
            rows.setdefault(json.dumps(t.user_attrs["params"], sort_keys=True), t.value)
    return [(json.loads(p), v) for p, v in sorted(rows.items(), key=lambda kv: -utility(kv[1]))]


def farther(params, sweep: FrameSet) -> int:
    return sum(is_farther(None if d is None or not math.isfinite(d) else d, f.branch_distance_m)
               for d, f in zip(branch_distances(params, sweep), sweep.frames))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("store", help="a tune's run store (REPORT/store.sqlite)")
    ap.add_argument("sweep", help="the rendered sweep at the tune's rig (an entry of tune's --sweep-cache)")
    ap.add_argument("--base", required=True, help="the tune's base parameter file")
    ap.add_argument("--base-value", type=float, required=True, help="the base's fitness in that tune (its report)")
    ap.add_argument("--metric", default="flown")
    ap.add_argument("--stride", type=int, default=10, help="read every N-th proposal by rank")
    args = ap.parse_args()
    print(machine_line())
    ranked = better_than_base(args.store, args.base_value, args.metric)
    sweep = FrameSet("sweep", tuple(load_frame(r) for r in iter_frames(args.sweep)))
    nb = farther(load_params(args.base), sweep)
    print(f"{len(ranked)} distinct proposals beat the base ({args.base_value:g}); the base reads {nb} of "
          f"{len(sweep)} sweep frames farther; reading every {args.stride}th")
    safe = []
    for rank in range(0, len(ranked), args.stride):
        params, value = ranked[rank]
        t0 = time.monotonic()
        n = farther(params_from_dict(params), sweep)
        print(f"rank {rank:4d}  fitness {value:.3f}: {n} farther ({time.monotonic() - t0:.0f} s)"
              f"{'  (no more than the base)' if n <= nb else ''}", flush=True)
        if n <= nb:
            safe.append(rank)
    print(f"no more farther than the base: {len(safe)} of {len(range(0, len(ranked), args.stride))} read"
          + (f" (ranks {safe})" if safe else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
