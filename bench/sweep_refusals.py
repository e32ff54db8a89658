"""What the tuner's safety sweep refuses: the stored candidates of a ``uav-depth tune`` run, read again on the
sweep at the log's rig, frame by frame against the base.

For each fold's best N candidates (training order, as ``tuning.choice.select`` offers them) this prints the
frames the candidate reads farther than the truth by more than 2 % and the base does not (with the base's own
reading there: too close / no measurement, or its error), and the frames inside the minimum range it sends as
distances. It is how docs/tuning.md (*Measured again: the default budget*, paragraph 3) found that the sweep's
refusals on the real pairs are frames inside the minimum range sent as distances, not noise.

    .venv/bin/python bench/sweep_refusals.py W/train W/row-0/store.sqlite --top 8
    .venv/bin/python bench/sweep_refusals.py W/train W/tuned/store.sqlite --base deploy/params-flight.yaml

``W`` is a ``bench/tune_real.py`` work folder (its training log and a row's store); any log and store of one
``tune`` run will do. ``--folds`` must be the run's (3 for the real pairs' six sessions).
"""

from __future__ import annotations

import argparse

from uav_depth.cli.benchmark import machine_line
from uav_depth.cli.tune_sweep import safety_frames
from uav_depth.core.params import DEFAULT_PARAMS, load_params, params_from_dict
from uav_depth.tuning.choice import top_candidates
from uav_depth.tuning.frames import DiskFrames, FrameSet
from uav_depth.tuning.metrics import branch_signed, is_farther
from uav_depth.tuning.objective import FITNESS, branch_distances, frame_ranger
from uav_depth.tuning.safety import rig_sample
from uav_depth.tuning.split import load_folds
from uav_depth.tuning.store import RunStore, fold_study_name


def _reading(d: float | None, truth: float) -> str:
    return "none (too close or no measurement)" if d is None else f"{branch_signed(d, truth):+.1f} %"


class Sweep:
    """The sweep's frames (read from tune's cache, rendered there first when missing) and each reading."""

    def __init__(self, sample, name: str):
        self.sample, self.sweep = sample, safety_frames(sample, name)
        self.truth = self.sweep.truths
        self.frames = FrameSet("sweep", DiskFrames("sweep", [(self.sweep.path, i) for i in self.sweep.frame_ids])
                               .frames)

    def line(self, name: str, params) -> tuple[list[int], list[float | None]]:
        """Print ``params``' counts on the sweep; (the frames it reads farther, its readings)."""
        d, truth, keys = branch_distances(params, self.frames), self.truth, self.sweep.keys
        min_m = frame_ranger(self.sample, params).limits.min_distance_m
        far = [k for k in range(len(d)) if is_farther(d[k], truth[k])]
        inside = [k for k in range(len(d)) if truth[k] < min_m and d[k] is not None]
        print(f"{name}: minimum range {min_m:.3f} m; farther than 2 %: {len(far)}; inside the minimum range "
              f"sent as a distance: {len(inside)}" + "".join(f"\n    {keys[k]} truth {truth[k]:.3f} m: "
                                                             f"{d[k]:.3f} m" for k in inside))
        return far, d


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logdir", help="the tune's training log")
    ap.add_argument("store", help="the tune's Optuna store (store.sqlite)")
    ap.add_argument("--base", help="the tune's --base (default: the manual baseline)")
    ap.add_argument("--folds", type=int, default=3)
    ap.add_argument("--top", type=int, default=8, help="candidates per fold, best training value first")
    ap.add_argument("--metric", default="flown")
    ap.add_argument("--sweep", choices=("standard", "quick"), default="standard")
    args = ap.parse_args(argv)

    base = load_params(args.base) if args.base else DEFAULT_PARAMS
    folds = load_folds(args.logdir, args.folds, FITNESS[args.metric].needs)
    sample = rig_sample(folds[0][0])
    if sample is None:
        raise SystemExit("no calibrated training frame: the tuner runs no safety sweep on this log")
    sweep = Sweep(sample, args.sweep)
    print(machine_line())
    print(f"safety sweep: {len(sweep.truth)} frames at {sample.left.shape[1]}x{sample.left.shape[0]}, f = "
          f"{sample.focal_px:.1f} px, B = {sample.baseline_m:.3f} m (the rig of {sample.key})")
    base_far, base_d = sweep.line("base", base)
    for j in range(args.folds):
        store = RunStore(args.store, "minimize", (), study_name=fold_study_name(j))
        for i, (p, value) in enumerate(top_candidates(store, args.metric, args.top)):
            far, d = sweep.line(f"fold {j + 1} #{i} (train {value:.4g})", params_from_dict(p))
            for k in far:
                if k not in base_far:
                    print(f"    farther, the base not: {sweep.sweep.keys[k]} truth {sweep.truth[k]:.3f} m: "
                          f"{_reading(d[k], sweep.truth[k])}, the base {_reading(base_d[k], sweep.truth[k])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
