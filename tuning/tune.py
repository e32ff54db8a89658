"""One tune, start to decision: the frames split by role, every fold's search, its choice on its validation
frames, the pooling over folds, and the gate on test frames nothing in the choice saw. :func:`tune` returns a
:class:`~uav_depth.tuning.gate.Decision`; the CLI parses, prints and writes only.

Roles: :mod:`.split` says which frames each step sees, :mod:`.study` searches one training set,
:mod:`.choice` chooses among its best candidates on validation frames, :mod:`.robust` pools the fold winners,
:mod:`.safety` screens candidates on synthetic branches at the log's rig, :mod:`.gate` judges on the test frames
and says whether the result may be written. The choice runs through an executor that refuses the test frames
(:class:`Sealed`): a choice that asked for them would fail the tune, not pass unnoticed.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

from uav_depth.core.errors import ConfigError, UavDepthError
from uav_depth.core.params import StereoParams, params_from_dict
from uav_depth.core.ranging import RangingConfig

from uav_depth.tuning.choice import SELECT_POOL, Selection, full_scores, select, top_candidates
from uav_depth.tuning.executor import Executor, Feed, make_executor
from uav_depth.tuning.frames import FrameData, FrameSet
from uav_depth.tuning.front import choose_under_budget, search_front, time_params
from uav_depth.tuning.gate import Decision, Verdict, refusal
from uav_depth.tuning.guide import SearchGuide
from uav_depth.tuning.objective import FITNESS, FLOWN_FITNESS, FLOWN_RANGING, Task, default_convention
from uav_depth.tuning.optimizers import OPTIMIZERS, make_space
from uav_depth.tuning.robust import CrossSelection, cross_select, farther_check
from uav_depth.tuning.safety import UNSAFE, SafetyScreen, SweepFrames, rig_sample
from uav_depth.tuning.space import describe_space, parse_keys
from uav_depth.tuning.split import TEST, Split, plan, set_names
from uav_depth.tuning.store import RunStore, fold_study_name
from uav_depth.tuning.study import Study, StudyConfig, StudyResult, TuneInterrupted

__all__ = ["Decision", "Hooks", "LeakError", "Sealed", "TuneInterrupted", "TuneRequest", "study_config", "tune"]

#: Frames the timing beside the result runs on (each parameter set once per frame, in this process).
TIMING_FRAMES = 4


def study_config(optimizer: str, metric: str | None, keys: str | None, max_ms: float | None, population: int,
                 generations: int, runs: int, seed: int) -> StudyConfig:
    """The study's settings from the command line's: the metric defaults to the paper's mse for ga-paper and
    to flown otherwise; ``keys`` as :func:`space.parse_keys` (speed keys added with ``max_ms``)."""
    if max_ms is not None and not max_ms > 0:
        raise ConfigError("--max-ms", "must be greater than 0", max_ms)
    metric = metric or ("mse" if optimizer == "ga-paper" else "flown")
    return StudyConfig(metric=metric, optimizer=optimizer, population=population, generations=generations,
                       runs=runs, seed=seed, keys=parse_keys(keys, speed=max_ms is not None,
                                                              flown=metric in FLOWN_FITNESS))


@dataclass(frozen=True)
class TuneRequest:
    """What one tune needs. ``store_path``: the Optuna storage (one study per fold). ``test``, ``holdout``,
    ``folds``: which frames play which role (:mod:`.split`). ``timeout_s``: wall time for all searches
    together; ``max_ms``: frame-time budget. ``ranging``: the ``ranging:`` section of the config that will fly
    (every evaluation ranges with it)."""

    logdir: str
    config: StudyConfig
    base: StereoParams
    store_path: str
    holdout: str | None = "auto"
    folds: str | None = "auto"
    test: str | None = "auto"
    resume: bool = False
    timeout_s: float | None = None
    max_ms: float | None = None
    workers: int | None = None
    ray_address: str | None = None
    ranging: RangingConfig = FLOWN_RANGING
    #: The safety sweep rendered at the rig of a given frame of the log (its size, focal length and baseline),
    #: as a session on disk, or None for no safety sweep. Injected by the caller: the tuner renders nothing.
    safety: Callable[[FrameData], SweepFrames] | None = None
    #: The search guide (:mod:`.guide`) at that rig, the same way; None: the search reads no guide.
    guide: Callable[[FrameData], SweepFrames] | None = None

    def __post_init__(self) -> None:
        if self.timeout_s is not None and not self.timeout_s > 0:
            raise ConfigError("--timeout", "must be greater than 0 seconds", self.timeout_s)


def _quiet(*_: Any) -> None:
    return None


def _same(executor: Executor, what: str) -> Executor:
    return executor


@dataclass(frozen=True)
class Hooks:
    """How a tune talks to whoever watches it; every hook is optional.

    ``phase(text)``: a step begins; ``begin(total)``: the searches start (total = candidates they may
    answer, for a progress bar); ``progress(n, value)``: n more answered, the latest value (n = 0: still
    working on one, the search guide reading it);
    ``searched()``: the last search ended; ``count(executor, what)``: wraps the executor for the scoring
    after the searches (a terminal counter); ``step(what, done, total)``: frames of the safety sweep read so far.
    ``stop``: set it to stop at the next result (``TuneInterrupted``).
    """

    phase: Callable[[str], None] = _quiet
    begin: Callable[[int], None] = _quiet
    progress: Callable[[int, float], None] | None = None
    searched: Callable[[], None] = _quiet
    count: Callable[[Executor, str], Executor] = _same
    step: Callable[[str, int, int], None] = _quiet
    stop: threading.Event | None = None


class LeakError(UavDepthError):
    """The choice asked for frames only the gate may see: its figures would not be held out."""


class Sealed:
    """An executor that refuses tasks on the ``sealed`` frame sets (the test frames, during the choice)."""

    def __init__(self, executor: Executor, sealed: Sequence[str] = (TEST,)):
        self._executor, self.sealed = executor, tuple(sealed)

    def imap(self, tasks: Sequence[Task], stop: threading.Event | None = None) -> Iterator:
        tasks = list(tasks)
        self._check(tasks)
        return self._executor.imap(tasks, stop)

    def stream(self, feed: Feed, stop: threading.Event | None = None) -> Iterator:
        def checked():
            item = feed()
            if item is not None:
                self._check([item[1]])
            return item
        return self._executor.stream(checked, stop)

    def _check(self, tasks: Sequence[Task]) -> None:
        leaked = sorted({t.frameset for t in tasks if t.frameset in self.sealed})
        if leaked:
            raise LeakError(f"the choice asked to score candidates on the {', '.join(leaked)} frames, which only "
                            "the gate may see: its figures would not be held out")

    def __getattr__(self, name: str) -> Any:
        return getattr(self._executor, name)


def _at_rig(request: TuneRequest, split: Split) -> tuple[SweepFrames | None, SearchGuide | None]:
    """The safety sweep and the search guide at the rig most training frames share, each rendered when first
    needed (or found in the caller's cache); None for what the request has not, or without a calibrated frame.
    The guide only for an optimiser that takes it."""
    sample = rig_sample(split.folds[0][0])
    if sample is None:
        return None, None
    sweep = request.safety(sample) if request.safety is not None else None
    guided = request.guide is not None and OPTIMIZERS[request.config.optimizer].guided
    return sweep, SearchGuide(request.guide(sample)) if guided else None


def tune(request: TuneRequest, hooks: Hooks = Hooks()) -> Decision:
    """Split, search, choose and gate (module docstring). Raises ``TuneInterrupted`` when ``hooks.stop`` is set
    (every finished evaluation is in the store), ``LeakError`` when the choice asks for the test frames,
    ``ConfigError`` / ``UavDepthError`` on bad input."""
    fitness = FITNESS[request.config.metric]
    hooks.phase(f"loading the frames of {request.logdir}")
    split = plan(request.logdir, request.test, request.holdout, request.folds, fitness.needs)
    roles = split.roles()
    hooks.phase(f"{len(roles['train'])} training, {len(roles['validation'])} validation and {len(roles['test'])} "
                "test frame(s): the search trains, the choice chooses, the gate judges on the test frames alone")
    sweep, guide = _at_rig(request, split)
    framesets = {**split.framesets(), **(sweep.framesets() if sweep is not None else {}),
                 **(guide.framesets() if guide is not None else {})}
    tuned_keys = [d["key"] for d in describe_space(make_space(request.config.optimizer, request.config.keys))["dims"]]
    direction = "minimize" if fitness.direction < 0 else "maximize"
    stores = [RunStore(request.store_path, direction, tuned_keys, study_name=fold_study_name(j))
              for j in range(split.k)]
    try:
        executor = make_executor(framesets, request.config.metric, request.workers, request.ray_address,
                                 request.ranging)
        try:
            if hasattr(executor, "warm"):
                hooks.phase(f"starting {executor.workers} evaluating processes (each loads the frames once)")
                executor.warm(lambda done, total: hooks.step("evaluating processes started", done, total))
            screen = SafetyScreen(sweep, request.base, executor, hooks.step, hooks.stop, hooks.phase)
            searches = _search(request, split, executor, stores, hooks, guide)
            selection, selections, cross = _choose(request, split, executor, searches, screen, tuned_keys, hooks)
            decision = _judge(request, split, framesets, executor, searches, selection, selections, cross,
                              screen, hooks)
            decision.points = [(ev.ms, ev.value) for _, p, ev in stores[0].evaluations()
                               if ev.ok and math.isfinite(ev.ms)]
            decision.front = search_front(stores[0], request.config.metric)
        finally:
            executor.close()
    finally:
        for st in stores:
            st.close()
    return decision


@dataclass
class _Search:
    """One fold's search: its study, its result, the candidates its choice may take, its budget choice."""

    study: Study
    result: StudyResult
    candidates: list[tuple[dict[str, Any], float]]
    budget: dict[str, Any] | None = None
    guide: dict[str, Any] | None = None


def _search(request: TuneRequest, split: Split, executor: Executor, stores: list[RunStore],
            hooks: Hooks, guide: SearchGuide | None = None) -> list[_Search]:
    """Every fold's search on its training frames, in turn, under one deadline; the bar counts all of them. With
    ``guide``, each search is led by it and its choice takes the candidates it found feasible first."""
    config = request.config
    hooks.begin(split.k * (config.runs * config.budget + 1))
    deadline = None if request.timeout_s is None else time.monotonic() + request.timeout_s
    out = []
    for j, ((tn, _), (tr, _), st) in enumerate(zip(set_names(split.k), split.folds, stores)):
        left = None if deadline is None else max(1e-3, deadline - time.monotonic())
        study = Study(config, tr, executor, st, request.base, progress=hooks.progress, stop=hooks.stop,
                      timeout_s=left, frameset=tn, ranging=request.ranging, guide=guide)
        study.open(request.resume)
        if j == 0 and guide is not None:
            hooks.phase(f"the search reads each candidate that beats the base on the {len(guide)} frames of the "
                        "search guide too (branches at the log's rig, seeds the safety sweep does not use)")
        result = study.run()
        if j == split.k - 1:
            hooks.searched()
        result.best_params()        # raises when every candidate failed
        search = _Search(study, result, top_candidates(st, config.metric, SELECT_POOL, result.baseline.value,
                                                       None if guide is None else guide.feasible),
                         guide=None if guide is None else _guide_counts(st, config.metric, guide,
                                                                        result.baseline.value))
        if request.max_ms is not None:
            hooks.phase(f"re-timing the search front under --max-ms {request.max_ms:g}")
            choice = choose_under_budget(st, config.metric, tr, request.max_ms)
            search.budget = {"max_ms": request.max_ms, "front": choice.front, "reason": choice.reason,
                             "chosen": None if choice.params is None else
                             {"value": choice.value, "ms": choice.ms, "params": choice.params.to_dict()}}
            search.candidates = [] if choice.params is None else [(choice.params.to_dict(), choice.value)]
        out.append(search)
    return out


def _guide_counts(store: RunStore, metric: str, guide: SearchGuide, base_value: float) -> dict[str, Any]:
    """What the guide found in one search: its frames, the base's reading there, the candidates evaluated, those
    that beat the base on the training frames (each read on the guide) and those of them that passed its rules."""
    utility = FITNESS[metric].utility
    evs = [ev for _, params, ev in store.evaluations() if ev.ok and not params.get("invalid")]
    better = [ev for ev in evs if utility(ev.value) > utility(base_value)]
    return {"frames": len(guide), "base_farther": guide.base_farther, "candidates": len(evs), "better": len(better),
            "better_and_feasible": sum(guide.feasible(ev) for ev in better)}


def _choose(request: TuneRequest, split: Split, executor: Executor, searches: list[_Search],
            screen: SafetyScreen, tuned_keys: list[str], hooks: Hooks
            ) -> tuple[Selection, list[Selection], CrossSelection | None]:
    """Each fold's choice on its validation frames, then the pooling over folds; the test frames are sealed."""
    sealed = Sealed(executor)
    metric, k = request.config.metric, split.k
    selections = []
    for j, ((tn, vn), (_, va), search) in enumerate(zip(set_names(k), split.folds, searches)):
        fold = f" (fold {j + 1} of {k})" if k > 1 else ""
        hooks.phase(f"choosing among the best candidates on the {len(va)} validation frame(s){fold}" if len(va)
                    else "choosing among the best candidates on the training frames (no validation frame)")
        selections.append(select(hooks.count(sealed, "candidates scored"), metric, request.base,
                                 search.result.baseline.value, search.candidates, bool(len(va)), train_set=tn,
                                 validation_set=vn, nudge_keys=tuned_keys,
                                 screen=screen.reject if screen.active else None))
    if k == 1:
        return selections[0], selections, None
    hooks.phase(f"scoring the {k} fold winners on every fold's validation sessions")
    cross = cross_select(hooks.count(sealed, "candidates scored"), metric, request.base, selections,
                         [vn for _, vn in set_names(k)])
    return _pooled_selection(FITNESS[metric], request.base, searches[0].result, selections, cross), selections, cross


def _pooled_selection(fitness, base: StereoParams, result: StudyResult, selections: list[Selection],
                      cross: CrossSelection) -> Selection:
    """The k-fold choice as one Selection: the base (its mean validation value) and each pooled fold winner
    (its mean over every fold's validation sessions, for the report), the winner ``cross.winner`` (the largest
    gain over the base on its own fold's validation sessions)."""
    rows = [{"params": base.to_dict(), "train": result.baseline.value, "validation": cross.cv_base, "fragile": None}]
    rows += [{"params": p["params"], "train": selections[p["fold"]].chosen["train"], "validation": p["mean"],
              "fragile": None, "fold": p["fold"] + 1, "validation_per_fold": p["validation"]} for p in cross.pool]
    for r in rows:
        r["train_utility"], r["validation_utility"] = fitness.utility(r["train"]), fitness.utility(r["validation"])
    return Selection(rows, 0 if cross.winner is None else cross.winner + 1, "validation")


def _judged_set(split: Split, selection: Selection) -> str:
    """The frames the gate judges on: the test frames, else those the choice was made on (the report says so)."""
    if len(split.test):
        return TEST
    return "validation" if selection.on == "validation" else "train"


def _judge(request: TuneRequest, split: Split, framesets: dict[str, Any], executor: Executor,
           searches: list[_Search], selection: Selection, selections: list[Selection],
           cross: CrossSelection | None, screen: SafetyScreen, hooks: Hooks) -> Decision:
    """The gate on the chosen parameters (module docstring of :mod:`.gate`) and the decision."""
    metric, base = request.config.metric, request.base
    fitness = FITNESS[metric]
    chosen = params_from_dict(selection.chosen["params"])
    names = [n for n in ("train", "validation", TEST) if len(framesets[n])]
    on = _judged_set(split, selection)
    hooks.phase("scoring the base and the chosen parameters with every metric on " + ", ".join(names))
    scores = full_scores(hooks.count(executor, "scored"), [base, chosen], names, default_convention(metric))
    base_ev, tuned_ev = scores[(0, on)], scores[(1, on)]
    farther = farther_check([base_ev], [tuned_ev], on)
    safety = screen.check(chosen) if selection.beats_base else None     # refused anyway: no sweep to pay for
    beats = selection.beats_base and fitness.utility(tuned_ev.value) > fitness.utility(base_ev.value)
    budget = searches[0].budget
    blocked = f"--max-ms: {budget['reason']}" if budget and budget["reason"] else None
    screened = sum(str(r.get("fragile") or "").startswith(UNSAFE) for sel in selections for r in sel.rows)
    refused = refusal(metric, selection, on, len(framesets[on]), base_ev.value, tuned_ev.value, beats,
                      [farther, safety], screened)
    verdict = Verdict(on, len(framesets[on]), base_ev.value, tuned_ev.value, beats, farther, safety, refused)
    frame_ms = None
    if chosen != base:
        hooks.phase("timing the base and the chosen parameters side by side, as the daemon flies them")
        timing = framesets[on] if len(framesets[on]) else framesets["train"]
        timing = FrameSet(timing.name, timing.frames[:TIMING_FRAMES])
        frame_ms = (time_params(base, timing, repeats=1), time_params(chosen, timing, repeats=1))
    return Decision(request, split, framesets, names, [s.study for s in searches], [s.result for s in searches],
                    selection, selections, cross, chosen, scores, verdict, budget, [], blocked, executor.kind,
                    executor.workers, frame_ms=frame_ms,
                    guide=None if searches[0].guide is None else [s.guide for s in searches])

