"""uav-depth tune LOGDIR: search SGBM+WLS parameters on logged frames, write a parameter file and a report."""

from __future__ import annotations

import argparse
import os

from uav_depth.cli.overrides import add_set_option, apply_sets

DEFAULT_STORE = "uav-depth-tune.sqlite"


def configure(p: argparse.ArgumentParser) -> None:
    from uav_depth.tuning.objective import FITNESS
    from uav_depth.tuning.optimizers import OPTIMIZERS

    p.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    p.add_argument("--metric", choices=list(FITNESS), default=None,
                   help="fitness. flown (default): what the daemon ranges on, the confident measured pixels over "
                        "the matched region, mean absolute error in the benchmark convention, plus the branch "
                        "distance error in the ranging region where the frames know it; flown-bad2: bad-2 instead; mse, psnr, ssim, "
                        "bad2: the paper's, on the WLS map (default with ga-paper); branch: the branch distance "
                        "alone (synthetic sessions); selfsup: needs no reference")
    p.add_argument("--optimizer", choices=list(OPTIMIZERS), default="tpe",
                   help="ga-paper: the paper's GA, faithful; ga: real-coded GA on the improved space from the "
                        "base parameters; random; tpe: Optuna's TPE on the improved space (default: it generalised "
                        "best to held-out frames in our measurements, see the README)")
    p.add_argument("--population", type=int, default=30, help="candidates per generation (default 30, the paper's)")
    p.add_argument("--generations", type=int, default=100, help="generations (default 100, the paper's)")
    p.add_argument("--runs", type=int, default=1, help="independent runs, seeds derived from --seed (paper: 30)")
    p.add_argument("--seed", type=int, default=0, help="base seed; same seed and data, same result (default 0)")
    p.add_argument("--keys", default=None,
                   help="schema keys the improved space tunes, comma-separated: 'default' = the paper's nine + "
                        "sgbm.block_size, 'paper' = the nine, 'speed' = compute.scale and compute.grey (added to "
                        "the default with --max-ms); ignored by ga-paper")
    p.add_argument("--holdout", default="auto",
                   help="frames the search never trains on; the winner is chosen on them and --out is written "
                        "only when it beats the base on them. auto (default): the last third of the sessions "
                        "(30%% of the frames of a single session); none; a fraction (0.3); a directory; or a "
                        "comma list of session names / session/frame keys / frame ids")
    p.add_argument("--folds", default="auto",
                   help="k-fold over sessions: each fold searches on the other sessions and chooses on its own; "
                        "the winner is the fold winner with the largest gain over the base on its own held-out "
                        "sessions (the only ones it did not train on), the gate the "
                        "cross-validated estimate. auto (default, with --holdout auto): 3 folds when the log has "
                        "2..8 sessions (k times the search cost), else one split; 1: one split")
    p.add_argument("--force", action="store_true",
                   help="write --out even when the result does not beat the base on the held-out frames")
    p.add_argument("--timeout", type=float, default=None,
                   help="stop starting generations after this many seconds and finish with what was found "
                        "(--resume continues it)")
    p.add_argument("--base", default=None,
                   help="parameter file the search starts from and keeps for untuned keys "
                        "(default: the built-in manual baseline)")
    add_set_option(p, "the base before the search (the search range per data set, for example)")
    p.add_argument("--workers", type=int, default=None, help="evaluating processes (default: all cores)")
    p.add_argument("--ray-address", default=None,
                   help="evaluate on Ray: 'local' starts one here, 'auto' or ray://HOST:PORT joins a cluster")
    p.add_argument("--out", default=None,
                   help="write the chosen parameters here (atomic, validated, provenance, the existing file's owner "
                        "and mode kept) when they beat the base on the held-out frames; else OUT.rejected.yaml "
                        "beside it and exit 1")
    p.add_argument("--report", default=None, help="write the report into this directory")
    p.add_argument("--store", default=None,
                   help=f"run store: an Optuna storage (a SQLite file, or an Optuna storage URL) that "
                        f"optuna-dashboard opens (default: REPORT/store.sqlite, else ./{DEFAULT_STORE})")
    p.add_argument("--resume", action="store_true",
                   help="continue the run held in the store (more --generations or --runs extend it)")
    p.add_argument("--max-ms", type=float, default=None,
                   help="choose the best candidate whose frame time (re-timed here) is at most this")
    p.add_argument("--safety-sweep", choices=("standard", "quick", "none"), default="standard",
                   help="standard (default): read each candidate about to win on synthetic branches from inside the "
                        "minimum range out to 3 m (330 frames rendered at the log's rig), set it aside when it reads "
                        "more of those frames farther than the truth than the base does or ranges a scene variant "
                        "less accurately, and refuse to write such a choice; quick: 84 frames (weaker: for trying "
                        "things out); none: skip")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _store_path(args: argparse.Namespace) -> str:
    if args.store:
        return args.store
    if args.report:
        return os.path.join(args.report, "store.sqlite")
    return DEFAULT_STORE


def rejected_path(out: str) -> str:
    """Where a candidate that did not beat its base is written: beside --out, never over it."""
    root, ext = os.path.splitext(out)
    return f"{root}.rejected{ext or '.yaml'}"


def safety_frames(sample, sweep: str = "standard"):
    """The named sweep of uav_depth.sim.sweep (SWEEPS) rendered at the rig of ``sample`` (a FrameData of the log):
    its image size, focal length and baseline; each frame knows the nearest significant object's distance."""
    from uav_depth.sim.sweep import SWEEPS, render_with_truth
    from uav_depth.tuning.frames import FrameData, FrameSet

    h, w = sample.left.shape[:2]
    frames = []
    for key, cfg in SWEEPS[sweep](w, h, sample.focal_px, sample.baseline_m):
        left, right, truth_m, roi = render_with_truth(cfg)
        frames.append(FrameData(f"safety/{key}", left, right, branch_distance_m=truth_m, roi=roi,
                                focal_px=cfg.focal_px, baseline_m=cfg.baseline_m, reference_source="synthetic"))
    return FrameSet("safety", tuple(frames))


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.progress import Counted, Progress

    terminal = Progress(enabled=False if args.no_progress else None)   # the phases outside the bar
    terminal.phase("loading the tuner")     # its imports take seconds on a small machine
    import datetime
    import functools
    import math
    import signal
    import sys
    import threading

    import cv2
    from tqdm import tqdm

    from uav_depth.core import __version__
    from uav_depth.cli.exit_codes import EXIT_ERROR, EXIT_INTERRUPTED
    from uav_depth.core.params import DEFAULT_PARAMS, load_params, save_params

    from uav_depth.tuning.objective import FITNESS
    from uav_depth.tuning.report import MANUAL_BASELINE, sources_text, write_report
    from uav_depth.tuning.space import describe_space
    from uav_depth.tuning.study import TuneInterrupted
    from uav_depth.tuning.tune import Hooks, TuneRequest, study_config, tune

    config = study_config(args.optimizer, args.metric, args.keys, args.max_ms, args.population, args.generations,
                          args.runs, args.seed)
    metric, fitness = config.metric, FITNESS[config.metric]
    base = apply_sets(load_params(args.base) if args.base else DEFAULT_PARAMS, args.overrides)
    request = TuneRequest(logdir=args.logdir, config=config, base=base, store_path=_store_path(args),
                          holdout=args.holdout, folds=args.folds, resume=args.resume, timeout_s=args.timeout,
                          max_ms=args.max_ms, workers=args.workers, ray_address=args.ray_address,
                          safety=(None if args.safety_sweep == "none" else
                                  functools.partial(safety_frames, sweep=args.safety_sweep)))

    # Signal handlers only set the event; the study stops at the next result and
    # keeps every finished evaluation. A second Ctrl-C interrupts at once.
    stop = threading.Event()

    def _on_signal(signum, frame):
        stop.set()
        signal.signal(signum, signal.SIG_DFL if signum != signal.SIGINT else signal.default_int_handler)

    bars: list = []
    best = {"u": -math.inf}

    def begin(total: int) -> None:
        bars.append(tqdm(total=total, unit="cand", disable=True if args.no_progress else None, dynamic_ncols=True,
                         desc=f"tune {metric}"))

    def progress(n: int, value: float) -> None:
        bars[0].update(n)
        if not math.isnan(value) and fitness.utility(value) > best["u"]:
            best["u"] = fitness.utility(value)
            bars[0].set_postfix_str(f"best {metric} {value:.4g}")

    def searched() -> None:
        bars[0].close()               # the phases after the last search print below the bar

    hooks = Hooks(phase=terminal.phase, begin=begin, progress=progress, searched=searched, stop=stop,
                  count=lambda executor, what: Counted(executor, terminal, what))
    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        decision = tune(request, hooks)
    except TuneInterrupted as exc:
        print(f"uav-depth tune: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        for bar in bars:
            bar.close()
        for s, h in previous.items():
            signal.signal(s, h)

    d, k, cross, selection, result = decision, decision.k, decision.cross, decision.selection, decision.result
    train, holdout, convention = d.train, d.holdout, d.convention
    summary = d.summary()
    summary.update(store=request.store_path,
                   base=(os.path.abspath(args.base) if args.base else MANUAL_BASELINE)
                   + "".join(f" --set {item}" for item in args.overrides))
    held_base, held_tuned = selection.base["holdout"], selection.chosen["holdout"]
    print(f"{args.optimizer} on {len(train)} train frame(s): {metric} base {result.baseline.value:.4g} -> "
          f"tuned {d.chosen_value:.4g}"
          + (f"; held-out ({len(holdout)}): {held_base:.4g} -> {held_tuned:.4g}" if len(holdout) and cross is None
             else "")
          + (f"; {k}-fold held-out: cross-validated {cross.cv_base:.4g} -> {cross.cv_tuned:.4g}, chosen mean "
             f"{held_base:.4g} -> {held_tuned:.4g}" if cross is not None else "")
          + f"  [{result.evaluated} evaluated, {result.cached} cached, {result.wall_s:.0f} s"
          + (", stopped by --timeout" if result.timed_out else "") + "]")
    if "reference" in fitness.needs:
        print("measured against: " + "; ".join(f"{name}: {sources_text(sources)}"
                                               for name, sources in summary["references"].items() if sources))
    if d.safety is not None:
        print(f"safety sweep ({d.safety.frames} synthetic frames at the log's rig): read farther than the truth by "
              f"more than 2 %: base {d.safety.base}, tuned {d.safety.tuned}")
    blocked, rejected = d.blocked, d.refused
    status = EXIT_ERROR if blocked or (rejected and args.out and not args.force) else 0
    if args.out and blocked is None:
        provenance = {
            "tool": "uav-depth tune", "version": __version__, "opencv": cv2.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "metric": metric, "convention": convention, "fitness": d.chosen_value,
            "baseline_fitness": result.baseline.value, "holdout_fitness": held_tuned,
            "holdout_baseline_fitness": held_base, "chosen_on": selection.on,
            "data": os.path.abspath(args.logdir), "frames": len(train), "frames_digest": d.study.digest,
            "holdout": args.holdout, "holdout_frames": len(holdout), "folds": k,
            "cv_fitness": None if cross is None else cross.cv_tuned,
            "cv_baseline_fitness": None if cross is None else cross.cv_base,
            "seed": args.seed, "optimizer": args.optimizer, "population": args.population,
            "generations": args.generations, "runs": args.runs, "best_run": result.best.run,
            "max_ms": args.max_ms, "store": os.path.abspath(request.store_path), "forced": bool(rejected),
            "references": summary["references"]["train"] if "reference" in fitness.needs else None}
        target = rejected_path(args.out) if status else args.out
        save_params(d.chosen, target, provenance)
        print(f"wrote {target}" + (f" (--force: {rejected})" if rejected and not status else ""))
    if blocked:
        print(f"uav-depth tune: error: {blocked}", file=sys.stderr)
    elif status:
        print(f"uav-depth tune: error: not written: {rejected}; the candidate is in {rejected_path(args.out)}; "
              "--force writes it anyway", file=sys.stderr)
    elif rejected and not args.out:
        print(f"uav-depth tune: warning: {rejected}", file=sys.stderr)
    if args.report:
        resolved = {"logdir": os.path.abspath(args.logdir), "holdout": args.holdout, "metric": metric,
                    "convention": convention, "optimizer": args.optimizer, "population": args.population,
                    "generations": args.generations, "runs": args.runs, "seed": args.seed,
                    "workers": d.workers, "executor": d.executor_kind, "ray_address": args.ray_address,
                    "max_ms": args.max_ms, "timeout_s": args.timeout, "store": request.store_path,
                    "space": describe_space(d.study.space), "base": base.to_dict(), "out": args.out,
                    "opencv": cv2.__version__, "version": __version__}
        terminal.phase(f"writing the report and its plots into {args.report}")
        write_report(args.report, summary, resolved, [d.framesets[n] for n in d.names], base, d.chosen, d.points)
        print(f"wrote report {args.report}")
    return status
