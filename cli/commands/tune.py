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
    p.add_argument("--test", default="auto",
                   help="frames set aside first, that only the gate and the report see (nothing in the choice "
                        "does): --out is written only when the result beats the base on them. auto (default): "
                        "the last quarter of the sessions (of a single session, its last 20%% of frames, which are "
                        "the same flight: the report warns that they are correlated); none (auto is none with "
                        "--holdout none); a fraction (0.2); a directory; or a comma list of session names / "
                        "session/frame keys / frame ids")
    p.add_argument("--holdout", default="auto",
                   help="of the frames left, those the search never trains on and the choice is made on "
                        "(validation). auto (default): k folds by session (below), else the last third of the "
                        "sessions (30%% of the frames of a single session); none; a fraction (0.3); a directory; "
                        "or a comma list of names, as --test")
    p.add_argument("--folds", default="auto",
                   help="k-fold over the sessions left after --test: each fold searches on the other sessions and "
                        "chooses on its own; the winner is the fold winner with the largest gain over the base on "
                        "its own validation sessions. auto (default, with --holdout auto): 3 folds when 2..8 "
                        "sessions are left (k times the search cost), else one split; 1: one split")
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
                        "minimum range out to 3 m (330 frames rendered at the log's rig, once per rig: see "
                        "--sweep-cache), set it aside when it reads more of those frames farther than the truth "
                        "than the base does or ranges a scene variant less accurately, and refuse to write such a "
                        "choice; with tpe the search reads each candidate that beats the base on 70 more "
                        "branches of other seeds as it goes (the search guide), to look where the sweep will pass; "
                        "quick: 84 frames (weaker: for trying things out); none: skip the sweep and the guide")
    p.add_argument("--sweep-cache", default=None,
                   help="where the rendered safety sweep is kept per rig (default: $XDG_CACHE_HOME/uav-depth/"
                        "safety-sweep, else ~/.cache/...); none: render into a temporary directory")
    p.add_argument("--config", default=None,
                   help="the run config the daemon will fly (its ranging: section is what every candidate is "
                        "ranged with); default: what run would load ($UAV_DEPTH_CONFIG), else the default "
                        "ranging settings")
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



def ranging_of(args: argparse.Namespace):
    """(the ranging settings every candidate is ranged with, where they came from): the ``ranging:`` section as
    run would resolve it: ``--config``, else ``$UAV_DEPTH_CONFIG``, with run's ``UAV_DEPTH_RANGING_*`` variables
    over it (also without a file), else the daemon's defaults. A config file run would refuse is refused here."""
    from uav_depth.cli.sources import SOURCES
    from uav_depth.daemon.config import load_section

    return load_section("ranging", args.config, sources=SOURCES, whole_file=True)


def build_request(args: argparse.Namespace, terminal, stop):
    """The TuneRequest of the command line (the frames are loaded by the tune itself)."""
    import functools

    from uav_depth.cli.tune_sweep import safety_frames
    from uav_depth.core.params import DEFAULT_PARAMS, load_params
    from uav_depth.tuning.tune import TuneRequest, study_config

    config = study_config(args.optimizer, args.metric, args.keys, args.max_ms, args.population, args.generations,
                          args.runs, args.seed)
    base = apply_sets(load_params(args.base) if args.base else DEFAULT_PARAMS, args.overrides)
    ranging, ranging_source = ranging_of(args)
    terminal.phase(f"ranging every candidate with {ranging_source}")
    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    safety = guide = None
    if args.safety_sweep != "none":     # the guide leads the search to what the sweep will pass: both or neither
        safety, guide = (functools.partial(
            safety_frames, sweep=name, cache=args.sweep_cache, workers=workers, phase=terminal.phase,
            progress=terminal.counter(f"{what}: frames rendered"), stop=stop)
            for name, what in ((args.safety_sweep, "safety sweep"), ("guide", "search guide")))
    return TuneRequest(logdir=args.logdir, config=config, base=base, store_path=_store_path(args),
                       holdout=args.holdout, folds=args.folds, test=args.test, resume=args.resume,
                       timeout_s=args.timeout, max_ms=args.max_ms, workers=args.workers,
                       ray_address=args.ray_address, ranging=ranging, safety=safety, guide=guide), ranging_source


def _hooks(args: argparse.Namespace, metric: str, terminal, stop, bars: list):
    """The progress bar of the searches and the terminal's phase and step lines."""
    import math

    from tqdm import tqdm

    from uav_depth.cli.progress import Counted
    from uav_depth.tuning.objective import FITNESS
    from uav_depth.tuning.tune import Hooks

    fitness, best = FITNESS[metric], {"u": -math.inf}

    def begin(total: int) -> None:
        bars.append(tqdm(total=total, unit="cand", disable=True if args.no_progress else None, dynamic_ncols=True,
                         desc=f"tune {metric}"))

    def progress(n: int, value: float) -> None:
        if n:
            bars[0].update(n)
        else:                       # still working on the same candidate (the search guide): redraw the clock
            bars[0].refresh()
        if not math.isnan(value) and fitness.utility(value) > best["u"]:
            best["u"] = fitness.utility(value)
            bars[0].set_postfix_str(f"best {metric} {value:.4g}")

    def searched() -> None:
        bars[0].close()               # the phases after the last search print below the bar

    return Hooks(phase=terminal.phase, begin=begin, progress=progress, searched=searched, stop=stop,
                 step=terminal.step, count=lambda executor, what: Counted(executor, terminal, what))


def _run_tune(request, args: argparse.Namespace, terminal, stop):
    """The tune under the terminal's hooks; the exit code instead when it was interrupted. Signal handlers only
    set the event; the tune stops at the next result and keeps every finished evaluation. A second Ctrl-C
    interrupts at once."""
    import signal
    import sys

    from uav_depth.cli.exit_codes import EXIT_INTERRUPTED
    from uav_depth.tuning.study import TuneInterrupted
    from uav_depth.tuning.tune import tune

    def _on_signal(signum, frame):
        stop.set()
        signal.signal(signum, signal.SIG_DFL if signum != signal.SIGINT else signal.default_int_handler)

    bars: list = []
    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return tune(request, _hooks(args, request.config.metric, terminal, stop, bars))
    except TuneInterrupted as exc:
        print(f"uav-depth tune: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        for bar in bars:
            bar.close()
        for s, h in previous.items():
            signal.signal(s, h)


def result_line(d, optimizer: str) -> str:
    """The one line that says what the tune found: training, validation and test figures, and the counts the
    progress bar showed."""
    sel, cross, metric, c = d.selection, d.cross, d.metric, d.counts
    train, valid, test = (d.framesets[n] for n in ("train", "validation", "test"))
    parts = [f"{optimizer} on {len(train)} train frame(s): {metric} base {d.result.baseline.value:.4g} -> tuned "
             f"{d.chosen_value:.4g}"]
    if cross is not None:
        parts.append(f"{d.k}-fold validation (chosen on it): {cross.cv_base:.4g} -> {cross.cv_tuned:.4g}")
    elif len(valid):
        parts.append(f"validation ({len(valid)}, chosen on it): {sel.base['validation']:.4g} -> "
                     f"{sel.chosen['validation']:.4g}")
    if len(test):
        parts.append(f"test ({len(test)}, unseen by the choice): {d.verdict.base_value:.4g} -> "
                     f"{d.verdict.tuned_value:.4g}")
    wall = sum(r.wall_s for r in d.results)
    return ("; ".join(parts) + f"  [{c['candidates']} candidates: {c['evaluated']} evaluated, {c['cached']} from the "
            f"cache, {wall:.0f} s" + (", stopped by --timeout" if any(r.timed_out for r in d.results) else "") + "]")


def _provenance(d, args: argparse.Namespace, summary: dict, request) -> dict:
    import datetime

    import cv2

    from uav_depth.core import __version__
    from uav_depth.tuning.objective import FITNESS

    sel, cross, v = d.selection, d.cross, d.verdict
    return {
        "tool": "uav-depth tune", "version": __version__, "opencv": cv2.__version__,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "metric": d.metric, "convention": d.convention, "fitness": d.chosen_value,
        "baseline_fitness": d.result.baseline.value, "validation_fitness": sel.chosen["validation"],
        "validation_baseline_fitness": sel.base["validation"], "chosen_on": sel.on,
        "judged_on": v.on, "judged_fitness": v.tuned_value, "judged_baseline_fitness": v.base_value,
        "data": os.path.abspath(args.logdir), "frames": len(d.framesets["train"]), "frames_digest": d.study.digest,
        "test": args.test, "test_frames": len(d.framesets["test"]), "holdout": args.holdout,
        "validation_frames": len(d.framesets["validation"]), "folds": d.k,
        "cv_fitness": None if cross is None else cross.cv_tuned,
        "cv_baseline_fitness": None if cross is None else cross.cv_base,
        "seed": args.seed, "optimizer": args.optimizer, "population": args.population,
        "generations": args.generations, "runs": args.runs, "best_run": d.result.best.run,
        "max_ms": args.max_ms, "store": os.path.abspath(request.store_path), "forced": bool(d.refused),
        "ranging": summary["ranging"],
        "references": summary["references"]["train"] if "reference" in FITNESS[d.metric].needs else None}


def _write_params(d, args: argparse.Namespace, summary: dict, request) -> int:
    """--out (or OUT.rejected.yaml beside it) and the refusal or warning line; the exit status."""
    import sys

    from uav_depth.cli.exit_codes import EXIT_ERROR
    from uav_depth.core.params import save_params

    blocked, rejected = d.blocked, d.refused
    status = EXIT_ERROR if blocked or (rejected and args.out and not args.force) else 0
    if args.out and blocked is None:
        target = rejected_path(args.out) if status else args.out
        save_params(d.chosen, target, _provenance(d, args, summary, request))
        print(f"wrote {target}" + (f" (--force: {rejected})" if rejected and not status else ""))
    if blocked:
        print(f"uav-depth tune: error: {blocked}", file=sys.stderr)
    elif status:
        print(f"uav-depth tune: error: not written: {rejected}; the candidate is in {rejected_path(args.out)}; "
              "--force writes it anyway", file=sys.stderr)
    elif rejected and not args.out:
        print(f"uav-depth tune: warning: {rejected}", file=sys.stderr)
    return status


def _write_report(d, args: argparse.Namespace, summary: dict, request, terminal) -> None:
    import cv2

    from uav_depth.core import __version__
    from uav_depth.tuning.report import write_report
    from uav_depth.tuning.space import describe_space

    resolved = {"logdir": os.path.abspath(args.logdir), "test": args.test, "holdout": args.holdout,
                "metric": d.metric, "convention": d.convention, "optimizer": args.optimizer,
                "population": args.population, "generations": args.generations, "runs": args.runs,
                "seed": args.seed, "workers": d.workers, "executor": d.executor_kind, "ray_address": args.ray_address,
                "max_ms": args.max_ms, "timeout_s": args.timeout, "store": request.store_path,
                "space": describe_space(d.study.space), "base": request.base.to_dict(), "out": args.out,
                "ranging": summary["ranging"], "opencv": cv2.__version__, "version": __version__}
    terminal.phase(f"writing the report and its plots into {args.report}")
    write_report(args.report, summary, resolved, [d.framesets[n] for n in d.names], request.base, d.chosen,
                 d.points, progress=terminal.counter("report: plots and images written"))
    print(f"wrote report {args.report}")


def _closing_lines(d, request) -> None:
    """Where every candidate is kept and how to browse it; a warning when the result is much slower."""
    import sys

    from uav_depth.tuning.store import storage_url

    url = storage_url(request.store_path)
    print(f"run store: {request.store_path} (every candidate, an Optuna study); browse it with: "
          f"optuna-dashboard {url}")
    if d.frame_ms is not None and d.frame_ms[1] > SLOWER_WARN * d.frame_ms[0]:
        b, t = d.frame_ms
        print(f"uav-depth tune: warning: the tuned parameters take {t:.0f} ms a frame, {t / b:.1f} x the base's "
              f"{b:.0f} ms (timed side by side here, as the daemon flies them); --max-ms MS bounds the frame time",
              file=sys.stderr)


#: Warn when the result takes more than this many times the base's frame time.
SLOWER_WARN = 2.0


def run(args: argparse.Namespace) -> int:
    import threading

    from uav_depth.cli.progress import Progress

    terminal = Progress(enabled=False if args.no_progress else None)   # the phases outside the bar
    terminal.phase("loading the tuner")     # its imports take seconds on a small machine
    stop = threading.Event()
    request, ranging_source = build_request(args, terminal, stop)
    d = _run_tune(request, args, terminal, stop)
    if isinstance(d, int):
        return d
    from dataclasses import asdict

    from uav_depth.tuning.objective import FITNESS
    from uav_depth.tuning.report import MANUAL_BASELINE, sources_text

    summary = d.summary()
    summary.update(store=request.store_path, ranging={"from": ranging_source, **asdict(request.ranging)},
                   base=(os.path.abspath(args.base) if args.base else MANUAL_BASELINE)
                   + "".join(f" --set {item}" for item in args.overrides))
    print(result_line(d, args.optimizer))
    for note in d.split.notes:
        print(f"note: {note}")
    if "reference" in FITNESS[d.metric].needs:
        print("measured against: " + "; ".join(f"{name}: {sources_text(sources)}"
                                               for name, sources in summary["references"].items() if sources))
    if d.guide is not None:
        g = d.guide
        print(f"search guide ({g[0]['frames']} branches at the log's rig, seeds the safety sweep does not use; the "
              f"base reads {g[0]['base_farther']} of them farther than the truth by more than 2 %): "
              f"{sum(f['better_and_feasible'] for f in g)} of the {sum(f['better'] for f in g)} candidates that beat "
              f"the base on their training frames passed the safety sweep's rules on it")
    if d.verdict.safety is not None:
        print(f"safety sweep ({d.verdict.safety.frames} synthetic frames at the log's rig): read farther than the "
              f"truth by more than 2 %: base {d.verdict.safety.base}, tuned {d.verdict.safety.tuned}")
    status = _write_params(d, args, summary, request)
    if args.report:
        _write_report(d, args, summary, request, terminal)
    _closing_lines(d, request)
    return status
