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
                   help="fitness. flown (default): what the daemon ranges on, the confident measured pixels in "
                        "the ranging region, mean absolute error in the benchmark convention, plus the branch "
                        "distance error where the frames know it; flown-bad2: bad-2 instead; mse, psnr, ssim, "
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
                        "the winner is the fold winner with the best mean held-out score, the gate the "
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


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.progress import Counted, Progress

    terminal = Progress(enabled=False if args.no_progress else None)   # the phases outside the bar
    terminal.phase("loading the tuner")     # its imports take seconds on a small machine
    import datetime
    import math
    import signal
    import sys
    import threading
    import time

    import cv2
    from tqdm import tqdm

    from uav_depth.core import __version__
    from uav_depth.cli.main import EXIT_ERROR, EXIT_INTERRUPTED
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.params import DEFAULT_PARAMS, load_params, params_from_dict, save_params

    from uav_depth.tuning.executor import make_executor
    from uav_depth.core.session import find_sessions
    from uav_depth.tuning.frames import load_folds, load_split
    from uav_depth.tuning.robust import cross_select, farther_check, parse_folds
    from uav_depth.tuning.objective import FITNESS, FLOWN_FITNESS, PAPER_FITNESS
    from uav_depth.tuning.optimizers import make_space
    from uav_depth.tuning.report import MANUAL_BASELINE, comparison, sources_text, write_report
    from uav_depth.tuning.space import describe_space, parse_keys
    from uav_depth.tuning.store import RunStore, fold_study_name
    from uav_depth.tuning.study import (Selection, Study, StudyConfig, TuneInterrupted, choose_under_budget,
                                        full_scores, result_summary, search_front, select, top_candidates)

    if args.max_ms is not None and not args.max_ms > 0:
        raise ConfigError("--max-ms", "must be greater than 0", args.max_ms)
    if args.timeout is not None and not args.timeout > 0:
        raise ConfigError("--timeout", "must be greater than 0 seconds", args.timeout)
    metric = args.metric or ("mse" if args.optimizer == "ga-paper" else "flown")
    keys = parse_keys(args.keys, speed=args.max_ms is not None, flown=metric in FLOWN_FITNESS)
    config = StudyConfig(metric=metric, optimizer=args.optimizer, population=args.population,
                         generations=args.generations, runs=args.runs, seed=args.seed, keys=keys)
    fitness = FITNESS[metric]
    # Reports: the paper's fitnesses are reported in the paper's convention, every other one as benchmarks do.
    convention = "paper" if metric in PAPER_FITNESS else "bench"
    terminal.phase(f"loading the frames of {args.logdir}")
    base = apply_sets(load_params(args.base) if args.base else DEFAULT_PARAMS, args.overrides)
    k = parse_folds(args.folds, len(find_sessions(args.logdir)), args.holdout)
    folds = load_folds(args.logdir, k, fitness.needs) if k > 1 else [load_split(args.logdir, args.holdout,
                                                                                 fitness.needs)]
    train, holdout = folds[0]
    set_names = [("train", "holdout")] + [(f"train{j}", f"holdout{j}") for j in range(1, k)]
    framesets = {}
    for (tn, hn), (tr, ho) in zip(set_names, folds):
        framesets[tn], framesets[hn] = tr, ho
    tuned_keys = [d["key"] for d in describe_space(make_space(args.optimizer, keys))["dims"]]
    direction = "minimize" if fitness.direction < 0 else "maximize"
    stores = [RunStore(_store_path(args), direction, tuned_keys, study_name=fold_study_name(j)) for j in range(k)]
    store = stores[0]

    # Signal handlers only set the event; the study stops at the next result and
    # keeps every finished evaluation. A second Ctrl-C interrupts at once.
    stop = threading.Event()

    def _on_signal(signum, frame):
        stop.set()
        signal.signal(signum, signal.SIG_DFL if signum != signal.SIGINT else signal.default_int_handler)

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    total = k * (config.runs * config.budget + 1)
    best = {"u": -math.inf}
    try:
        with tqdm(total=total, unit="cand", disable=True if args.no_progress else None, dynamic_ncols=True,
                  desc=f"tune {metric}") as bar:
            def progress(n: int, value: float) -> None:
                bar.update(n)
                if not math.isnan(value) and fitness.utility(value) > best["u"]:
                    best["u"] = fitness.utility(value)
                    bar.set_postfix_str(f"best {metric} {value:.4g}")

            executor = make_executor(framesets, metric, args.workers, args.ray_address)
            try:
                deadline = None if args.timeout is None else time.monotonic() + args.timeout
                results, selections, budget = [], [], None
                for j, ((tn, hn), (tr, ho), st) in enumerate(zip(set_names, folds, stores)):
                    left = None if deadline is None else max(1e-3, deadline - time.monotonic())
                    study_j = Study(config, tr, executor, st, base, progress=progress, stop=stop, timeout_s=left,
                                    frameset=tn)
                    study_j.open(args.resume)
                    result_j = study_j.run()
                    if j == k - 1:
                        bar.close()               # the phases after the last search print below the bar
                    result_j.best_params()        # raises when every candidate failed
                    if j == 0:
                        study, result = study_j, result_j
                    results.append(result_j)
                    if args.max_ms is not None:
                        terminal.phase(f"re-timing the search front under --max-ms {args.max_ms:g}")
                        choice = choose_under_budget(st, metric, tr, args.max_ms)
                        if j == 0:
                            budget = {"max_ms": args.max_ms, "front": choice.front,
                                      "chosen": None if choice.params is None else
                                      {"value": choice.value, "ms": choice.ms, "params": choice.params.to_dict()},
                                      "reason": choice.reason}
                        candidates = [] if choice.params is None else [(choice.params.to_dict(), choice.value)]
                    else:
                        candidates = top_candidates(st, metric)
                    fold = f" (fold {j + 1} of {k})" if k > 1 else ""
                    terminal.phase(f"choosing among the best candidates on the {len(ho)} held-out frame(s){fold}"
                                   if len(ho) else "choosing among the best candidates on the training frames")
                    selections.append(select(Counted(executor, terminal, "candidates scored"), metric, base,
                                             result_j.baseline.value, candidates, bool(len(ho)), train_set=tn,
                                             holdout_set=hn, nudge_keys=tuned_keys))
                cross = None
                if k > 1:
                    terminal.phase(f"scoring the {k} fold winners on every fold's held-out sessions")
                    cross = cross_select(Counted(executor, terminal, "candidates scored"), metric, base, selections,
                                         [hn for _, hn in set_names])
                    rows = [{"params": base.to_dict(), "train": result.baseline.value, "holdout": cross.cv_base,
                             "fragile": None}]
                    rows += [{"params": p["params"], "train": selections[p["fold"]].chosen["train"],
                              "holdout": p["mean"], "fragile": None, "fold": p["fold"] + 1,
                              "holdout_per_fold": p["holdout"]} for p in cross.pool]
                    for r in rows:
                        r["train_utility"], r["holdout_utility"] = (fitness.utility(r["train"]),
                                                                    fitness.utility(r["holdout"]))
                    selection = Selection(rows, 0 if cross.winner is None else cross.winner + 1, "holdout")
                else:
                    selection = selections[0]
                chosen = params_from_dict(selection.chosen["params"])
                chosen_value = selection.chosen["train"]
                front = search_front(store, metric)
                names = [n for n in ("train", "holdout") if len(framesets[n])]
                # the farther-reading gate counts on the frames the choice was made on (with folds: every fold's)
                gate_sets = [n for n in ([hn for _, hn in set_names] if selection.on == "holdout" else ["train"])
                             if len(framesets[n])]
                terminal.phase("scoring the base and the chosen parameters with every metric on "
                               + " and ".join(names))
                scores = full_scores(Counted(executor, terminal, "scored"), [base, chosen],
                                     names + [n for n in gate_sets if n not in names], convention)
            finally:
                executor.close()
    except TuneInterrupted as exc:
        print(f"uav-depth tune: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        for s, h in previous.items():
            signal.signal(s, h)

    # The gate: with folds, also the cross-validated estimate (each fold's winner on its own held-out sessions)
    # must beat the base's (every number in it held out).
    beats = selection.beats_base and (cross is None or fitness.utility(cross.cv_tuned) > fitness.utility(cross.cv_base))
    farther = farther_check([scores[(0, n)] for n in gate_sets], [scores[(1, n)] for n in gate_sets],
                            "held-out" if selection.on == "holdout" else "training")
    cmp = comparison({n: scores[(0, n)] for n in names}, {n: scores[(1, n)] for n in names})
    summary = result_summary(result)
    summary.update(comparison=cmp, convention=convention, budget=budget or {"max_ms": None, "front": front},
                   chosen={"value": chosen_value, "holdout_value": selection.chosen["holdout"],
                           "params": chosen.to_dict()},
                   selection={"on": selection.on, "winner": selection.winner, "beats_base": beats,
                              "farther": {"base": farther.base, "tuned": farther.tuned, "frames": farther.frames,
                                          "refused": farther.reason},
                              "candidates": selection.rows, "folds": _folds_summary(selections, folds, cross)},
                   frames={n: framesets[n].keys for n in names}, store=store.path,
                   references={n: framesets[n].reference_sources() for n in names},
                   base=(os.path.abspath(args.base) if args.base else MANUAL_BASELINE)
                   + "".join(f" --set {item}" for item in args.overrides),
                   evaluations_per_s=result.evaluated / result.wall_s if result.wall_s > 0 else None)
    held_base, held_tuned = selection.base["holdout"], selection.chosen["holdout"]
    print(f"{args.optimizer} on {len(train)} train frame(s): {metric} base {result.baseline.value:.4g} -> "
          f"tuned {chosen_value:.4g}"
          + (f"; held-out ({len(holdout)}): {held_base:.4g} -> {held_tuned:.4g}" if len(holdout) and cross is None
             else "")
          + (f"; {k}-fold held-out: cross-validated {cross.cv_base:.4g} -> {cross.cv_tuned:.4g}, chosen mean "
             f"{held_base:.4g} -> {held_tuned:.4g}" if cross is not None else "")
          + f"  [{result.evaluated} evaluated, {result.cached} cached, {result.wall_s:.0f} s"
          + (", stopped by --timeout" if result.timed_out else "") + "]")
    if "reference" in fitness.needs:
        print("measured against: " + "; ".join(f"{name}: {sources_text(sources)}"
                                               for name, sources in summary["references"].items() if sources))
    blocked = f"--max-ms: {budget['reason']}" if budget and budget["reason"] else None
    rejected = None
    if blocked is None and not beats:
        where = f"the {len(holdout)} held-out frame(s)" if selection.on == "holdout" else \
            "the training frames (no held-out frame)"
        if cross is not None:
            where = f"the held-out sessions of {k} folds"
            rejected = (f"the tuned parameters do not beat the base on {where} ({metric} cross-validated "
                        f"{cross.cv_tuned:.4g} vs base {cross.cv_base:.4g}; chosen, mean held-out "
                        f"{selection.chosen['holdout']:.4g} vs {selection.base['holdout']:.4g})")
        else:
            rejected = (f"the tuned parameters do not beat the base on {where} "
                        f"({metric} {selection.chosen[selection.on]:.4g} vs base {selection.base[selection.on]:.4g})")
    if blocked is None and farther.reason:      # reading farther than the branch is refused like a worse score
        rejected = farther.reason if rejected is None else f"{rejected}; {farther.reason}"
    status = EXIT_ERROR if blocked or (rejected and args.out and not args.force) else 0
    if args.out and blocked is None:
        provenance = {
            "tool": "uav-depth tune", "version": __version__, "opencv": cv2.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "metric": metric, "convention": convention, "fitness": chosen_value,
            "baseline_fitness": result.baseline.value, "holdout_fitness": held_tuned,
            "holdout_baseline_fitness": held_base, "chosen_on": selection.on,
            "data": os.path.abspath(args.logdir), "frames": len(train), "frames_digest": study.digest,
            "holdout": args.holdout, "holdout_frames": len(holdout), "folds": k,
            "cv_fitness": None if cross is None else cross.cv_tuned,
            "cv_baseline_fitness": None if cross is None else cross.cv_base,
            "seed": args.seed, "optimizer": args.optimizer, "population": args.population,
            "generations": args.generations, "runs": args.runs, "best_run": result.best.run,
            "max_ms": args.max_ms, "store": os.path.abspath(store.path), "forced": bool(rejected),
            "references": summary["references"]["train"] if "reference" in fitness.needs else None}
        target = rejected_path(args.out) if status else args.out
        save_params(chosen, target, provenance)
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
                    "workers": executor.workers, "executor": executor.kind, "ray_address": args.ray_address,
                    "max_ms": args.max_ms, "timeout_s": args.timeout, "store": store.path,
                    "space": describe_space(study.space), "base": base.to_dict(), "out": args.out,
                    "opencv": cv2.__version__, "version": __version__}
        points = [(ev.ms, ev.value) for _, p, ev in store.evaluations() if ev.ok and math.isfinite(ev.ms)]
        terminal.phase(f"writing the report and its plots into {args.report}")
        write_report(args.report, summary, resolved, [framesets[n] for n in names], base, chosen, points)
        print(f"wrote report {args.report}")
    for st in stores:
        st.close()
    return status


def _folds_summary(selections, folds, cross) -> list[dict]:
    """Per fold: its sessions, and the base's and its winner's train and held-out values (train vs held-out)."""
    out = []
    for j, (sel, (tr, ho)) in enumerate(zip(selections, folds)):
        out.append({"fold": j + 1, "train_frames": tr.keys, "holdout_frames": ho.keys,
                    "base_train": sel.base["train"], "base_holdout": sel.base["holdout"],
                    "winner_train": sel.chosen["train"], "winner_holdout": sel.chosen["holdout"],
                    "beats_base": sel.beats_base,
                    "rejected": [r["fragile"] for r in sel.rows if r.get("fragile")]})
    return out
