"""Tuner benchmark: evaluations per second and wall time of a fixed GA budget, 1 and N workers.

On scikit-image's Middlebury 2014 motorcycle pair (741x500, RGB -> BGR, its
ground truth), the same study (optimiser, seed, budget) is run as

- ``plain``: a plain serial loop: the optimiser, and every proposal evaluated
  on the spot, no cache, no executor (the reference result);
- ``1 worker``: the tuner's study in-process (cache of identical candidates);
- ``N workers``: the tuner's study on a local process pool;
- ``ray N`` (``--ray``): the study on a local Ray with N actors;

and every variant must end with the identical trajectory (each proposal's
fitness, bit for bit) and the identical best parameters, or the script fails.
Prints the machine (cores, CPU model), then one line per variant.

    python bench/tuner_bench.py                      # ga-paper, 30 x 10, 1 and all-core workers
    python bench/tuner_bench.py --generations 100 --skip-plain   # the paper's 30 x 100 protocol
    python bench/tuner_bench.py --workers 1 2 4 8 --ray          # scaling, process pool and Ray
    python bench/tuner_bench.py --write-session /tmp/moto        # the pair as a log for uav-depth tune
"""

from __future__ import annotations

import argparse
import math
import os
import time

import cv2
import numpy as np

from uav_depth.cli.benchmark import machine_line


def motorcycle():
    from skimage import data

    from uav_depth.tuning.frames import FrameData, FrameSet

    left, right, gt = data.stereo_motorcycle()
    frame = FrameData("skimage/motorcycle", cv2.cvtColor(left, cv2.COLOR_RGB2BGR),
                      cv2.cvtColor(right, cv2.COLOR_RGB2BGR), gt.astype(np.float32))
    return FrameSet("train", (frame,))


def write_motorcycle_session(path: str) -> None:
    """The motorcycle pair as a session in the log layout, for ``uav-depth tune PATH``."""
    from uav_depth.core.calibration import Calibration
    from uav_depth.core.session import SessionWriter
    from uav_depth.tuning.reference.provenance import make_provenance

    frame = motorcycle().frames[0]
    h, w = frame.left.shape[:2]
    # Middlebury 2014 Motorcycle at a quarter of full size: f = 3979.911 / 4 px, B = 0.193 m (only
    # recorded for completeness: no metric here converts its disparity to metres)
    cal = Calibration(focal_px=3979.911 / 4, baseline_m=0.193001, width=w, height=h)
    source = make_provenance("import", source="skimage.data.stereo_motorcycle (Middlebury 2014 ground truth)",
                             format="npy", scale=1.0)
    SessionWriter(path, cal).write(0, frame.left, frame.right, reference=frame.reference, reference_source=source)


def plain_loop(config, frames, base):
    """The reference: the optimiser with every proposal evaluated on the spot, no cache, no pool."""
    from uav_depth.core.errors import ConfigError
    from uav_depth.tuning.executor import EVAL_THREADS
    from uav_depth.tuning.objective import FITNESS, evaluate
    from uav_depth.tuning.optimizers import OPTIMIZERS, make_space
    from uav_depth.tuning.space import build

    cv2.setNumThreads(EVAL_THREADS)
    fitness = FITNESS[config.metric]
    space = make_space(config.optimizer, config.keys)
    trajectory, best = [], (-math.inf, None)
    evaluations = 0
    for run, seq in enumerate(np.random.SeedSequence(config.seed).spawn(config.runs)):
        opt = OPTIMIZERS[config.optimizer].factory(space, config.population, np.random.default_rng(seq), base)
        for gen in range(config.generations):
            utilities = []
            for genome in opt.ask():
                try:
                    params = build(space, genome, base)
                except ConfigError:
                    utilities.append(-math.inf)
                    continue
                ev = evaluate(params, frames, fitness)
                evaluations += 1
                u = fitness.utility(ev.value) if ev.ok else -math.inf
                utilities.append(u)
                if u > best[0]:
                    best = (u, params.to_dict())
            opt.tell(utilities)
            trajectory += utilities
    return trajectory, best[1], evaluations


def study(config, frames, base, workers, ray=False):
    from uav_depth.tuning.executor import RayExecutor, make_executor
    from uav_depth.tuning.store import RunStore
    from uav_depth.tuning.study import Study

    sets = {"train": frames}
    t0 = time.perf_counter()
    ex = RayExecutor(sets, config.metric, workers, "local") if ray else make_executor(sets, config.metric, workers)
    start_s = time.perf_counter() - t0
    try:
        store = RunStore()
        st = Study(config, frames, ex, store, base)
        st.candidate  # noqa: B018 - the study's own loop, timed below
        t1 = time.perf_counter()
        seeds = np.random.SeedSequence(config.seed).spawn(config.runs)
        runs = [st.run_one(i, s) for i, s in enumerate(seeds)]
        loop_s = time.perf_counter() - t1
    finally:
        ex.close()
    trajectory = [u if u is not None else -math.inf for *_, u in store.trials()]
    best = max(runs, key=lambda r: r.best_utility).best_params
    return trajectory, best, st.evaluated, start_s, loop_s


def main() -> int:
    from uav_depth.core.params import DEFAULT_PARAMS
    from uav_depth.tuning.study import StudyConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--optimizer", default="ga-paper")
    ap.add_argument("--metric", default="mse")
    ap.add_argument("--population", type=int, default=30)
    ap.add_argument("--generations", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, nargs="+", default=None,
                    help="worker counts to run (default: 1 and all cores)")
    ap.add_argument("--ray", action="store_true", help="also run each worker count > 1 on a local Ray")
    ap.add_argument("--skip-plain", action="store_true", help="skip the plain serial loop (slow for 30 x 100)")
    ap.add_argument("--write-session", metavar="DIR", help="only write the pair as a session for uav-depth tune")
    args = ap.parse_args()
    if args.write_session:
        write_motorcycle_session(args.write_session)
        print(f"wrote {args.write_session}")
        return 0

    config = StudyConfig(metric=args.metric, optimizer=args.optimizer, population=args.population,
                         generations=args.generations, seed=args.seed)
    frames = motorcycle()
    workers = args.workers or sorted({1, os.cpu_count() or 1})
    print(machine_line())
    print(f"study: {args.optimizer}, {args.metric}, population {args.population} x {args.generations} generations "
          f"= {config.budget} proposals, seed {args.seed}, motorcycle 741x500")
    print(f"{'variant':<14}{'wall s':>8}{'start s':>9}{'evaluated':>11}{'evals/s':>9}{'proposals/s':>13}"
          f"{'vs plain':>10}  identical")
    reference = None
    plain_s = None
    if not args.skip_plain:
        t0 = time.perf_counter()
        traj, best, n = plain_loop(config, frames, DEFAULT_PARAMS)
        plain_s = time.perf_counter() - t0
        reference = (traj, best)
        print(f"{'plain':<14}{plain_s:8.1f}{0:9.1f}{n:11d}{n / plain_s:9.2f}{len(traj) / plain_s:13.1f}"
              f"{1.0:10.2f}  (reference)")
    variants = [(w, False) for w in workers] + ([(w, True) for w in workers if w > 1] if args.ray else [])
    for w, on_ray in variants:
        traj, best, n, start_s, loop_s = study(config, frames, DEFAULT_PARAMS, w, on_ray)
        wall = start_s + loop_s
        if reference is None:
            reference = (traj, best)
            same = "(reference)"
        else:
            same = "yes" if (traj == reference[0] and best == reference[1]) else "NO"
        name = f"{'ray' if on_ray else 'workers'} {w}"
        vs = f"{plain_s / wall:10.2f}" if plain_s else f"{'':>10}"
        print(f"{name:<14}{wall:8.1f}{start_s:9.1f}{n:11d}{n / loop_s:9.2f}{len(traj) / wall:13.1f}{vs}  {same}")
        if same == "NO":
            print("error: a variant did not reproduce the reference result")
            return 1
    best_u = max(u for u in reference[0])
    print(f"best {args.metric}: {abs(best_u):.4g} ({'failed' if best_u == -math.inf else 'ok'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
