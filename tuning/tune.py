"""One tune, start to decision: every fold's search, its choice on its held-out sessions, the pooling over
folds, the final scores and the gate. :func:`tune` returns a :class:`Decision`; the CLI parses, prints and
writes only.

Roles: :mod:`.study` searches one frame set and chooses among its best candidates on held-out frames,
:mod:`.robust` splits into folds, pools the fold winners and checks farther readings; this module runs them
in order for one request and says whether the result may be written (:attr:`Decision.refused`) and why.

**The gate.** The chosen candidate may replace its base only when

- it beats the base on the frames it was chosen on (with folds: its mean over every fold's held-out sessions),
  and, with folds, the cross-validated estimate (each fold's winner on its own held-out sessions, every number
  held out) beats the base's there;
- it reads no more frames farther than the branch truth by more than 2 % than the base does, and its mean
  safety-weighted branch-distance error is no larger than the base's (a better map must not buy a worse
  distance), counted only
  on frames it did not train on: with folds, on its own fold's held-out sessions (a pooled winner trained on
  the other folds' held-out sessions), and in the cross-validated view (each fold's winner on its own held-out
  sessions) as well;
- on the safety sweep (``TuneRequest.safety``: synthetic frames the caller renders at the log's rig, from
  inside the minimum range out to the working distance), it reads no more frames farther than the truth than
  the base does, and no scene variant less accurately (:mod:`.safety`): a log holds few frames near the minimum
  range or with twigs in front, and those are where a tuned matcher goes wrong unseen (a file this gate wrote
  sent a branch inside the minimum range as a distance). The sweep also screens the held-out choice
  (:class:`~uav_depth.tuning.safety.SafetyScreen`): a candidate about to win that fails it is set aside and the
  next best tried, so an unsafe best does not cost a safe runner-up;
- with ``max_ms``, some evaluated candidate runs within the frame-time budget (else :attr:`Decision.blocked`).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import StereoParams, params_from_dict
from uav_depth.core.session import find_sessions

from uav_depth.tuning.executor import Executor, make_executor, run_all
from uav_depth.tuning.frames import FrameData, FrameSet, load_folds, load_split
from uav_depth.tuning.objective import FITNESS, FLOWN_FITNESS, Task, default_convention
from uav_depth.tuning.optimizers import make_space
from uav_depth.tuning.report import comparison
from uav_depth.tuning.robust import CrossSelection, FartherCheck, cross_select, farther_check, parse_folds
from uav_depth.tuning.safety import UNSAFE, SafetyScreen
from uav_depth.tuning.space import describe_space, parse_keys
from uav_depth.tuning.store import RunStore, fold_study_name
from uav_depth.tuning.choice import SELECT_POOL, Selection, full_scores, select, top_candidates
from uav_depth.tuning.front import choose_under_budget, search_front
from uav_depth.tuning.study import Study, StudyConfig, StudyResult, result_summary


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
    """What one tune needs. ``store_path``: the Optuna storage (one study per fold). ``folds``: ``--folds``
    (robust.parse_folds). ``timeout_s``: wall time for all searches together; ``max_ms``: frame-time budget."""

    logdir: str
    config: StudyConfig
    base: StereoParams
    store_path: str
    holdout: str | None = "auto"
    folds: str | None = "auto"
    resume: bool = False
    timeout_s: float | None = None
    max_ms: float | None = None
    workers: int | None = None
    ray_address: str | None = None
    #: The safety sweep's frames at the rig of a given frame of the log (its size, focal length and baseline),
    #: or None for no safety sweep. Injected by the caller: the tuner renders nothing itself.
    safety: Callable[[FrameData], FrameSet] | None = None

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
    evaluate, for a progress bar); ``progress(n, value)``: n more evaluated, the latest value;
    ``searched()``: the last search ended; ``count(executor, what)``: wraps the executor for the scoring
    after the searches (a terminal counter). ``stop``: set it to stop at the next result (``TuneInterrupted``).
    """

    phase: Callable[[str], None] = _quiet
    begin: Callable[[int], None] = _quiet
    progress: Callable[[int, float], None] | None = None
    searched: Callable[[], None] = _quiet
    count: Callable[[Executor, str], Executor] = _same
    stop: threading.Event | None = None


@dataclass
class Decision:
    """The outcome of :func:`tune`. ``chosen``: the parameters (the base when nothing beat it); ``refused``:
    why they may not replace the base (one line; None when they may); ``blocked``: why nothing can be
    written at all (``max_ms`` met by no candidate), else None. ``scores[(i, set)]``: full evaluations of the
    base (i = 0) and the chosen (i = 1) on ``names`` and on the sets the farther check counted on."""

    request: TuneRequest
    k: int
    framesets: dict[str, FrameSet]
    names: list[str]
    study: Study
    result: StudyResult
    selection: Selection
    selections: list[Selection]
    folds: list[tuple[FrameSet, FrameSet]]
    cross: CrossSelection | None
    chosen: StereoParams
    chosen_value: float
    scores: dict
    beats: bool
    farther: FartherCheck
    cv_farther: FartherCheck | None
    budget: dict[str, Any] | None
    front: list[dict[str, Any]]
    refused: str | None
    blocked: str | None
    executor_kind: str
    workers: int
    points: list[tuple[float, float]] = field(default_factory=list)
    #: The safety sweep's verdict on the chosen parameters, None when none ran (TuneRequest.safety, SafetyScreen.check).
    safety: FartherCheck | None = None

    @property
    def metric(self) -> str:
        return self.request.config.metric

    @property
    def convention(self) -> str:
        return default_convention(self.metric)

    @property
    def train(self) -> FrameSet:
        return self.folds[0][0]

    @property
    def holdout(self) -> FrameSet:
        return self.folds[0][1]

    def summary(self) -> dict[str, Any]:
        """summary.json's content of the decision (the CLI adds where the base and the frames came from)."""
        sel, cross = self.selection, self.cross
        far = _farther_doc(self.farther)
        if self.cv_farther is not None:
            far["cross_validated"] = _farther_doc(self.cv_farther)
        far["safety_sweep"] = None if self.safety is None else _farther_doc(self.safety)
        cmp = comparison({n: self.scores[(0, n)] for n in self.names}, {n: self.scores[(1, n)] for n in self.names})
        out = result_summary(self.result)
        out.update(comparison=cmp, convention=self.convention,
                   budget=self.budget or {"max_ms": None, "front": self.front},
                   chosen={"value": self.chosen_value, "holdout_value": sel.chosen["holdout"],
                           "params": self.chosen.to_dict()},
                   selection={"on": sel.on, "winner": sel.winner, "beats_base": self.beats, "farther": far,
                              "candidates": sel.rows, "folds": _folds_summary(self.selections, self.folds)},
                   frames={n: self.framesets[n].keys for n in self.names},
                   references={n: self.framesets[n].reference_sources() for n in self.names},
                   evaluations_per_s=self.result.evaluated / self.result.wall_s if self.result.wall_s > 0 else None)
        if cross is not None:
            out["selection"]["cross_validated"] = {"base": cross.cv_base, "tuned": cross.cv_tuned}
        return out


def _farther_doc(check: FartherCheck) -> dict[str, Any]:
    doc = {"base": check.base, "tuned": check.tuned, "frames": check.frames, "refused": check.reason,
           "base_branch_safe": check.base_safe, "tuned_branch_safe": check.tuned_safe}
    if check.base_median is not None:
        doc.update(base_median_abs_error=check.base_median, tuned_median_abs_error=check.tuned_median)
    return doc


def _folds_summary(selections: list[Selection], folds: list[tuple[FrameSet, FrameSet]]) -> list[dict]:
    """Per fold: its sessions, and the base's and its winner's train and held-out values (train vs held-out)."""
    out = []
    for j, (sel, (tr, ho)) in enumerate(zip(selections, folds)):
        out.append({"fold": j + 1, "train_frames": tr.keys, "holdout_frames": ho.keys,
                    "base_train": sel.base["train"], "base_holdout": sel.base["holdout"],
                    "winner_train": sel.chosen["train"], "winner_holdout": sel.chosen["holdout"],
                    "beats_base": sel.beats_base,
                    "rejected": [r["fragile"] for r in sel.rows if r.get("fragile")]})
    return out


def set_names(k: int) -> list[tuple[str, str]]:
    """The executor's (train, held-out) frame-set names of each fold: fold 0 is the plain train / holdout."""
    return [("train", "holdout")] + [(f"train{j}", f"holdout{j}") for j in range(1, k)]


def tune(request: TuneRequest, hooks: Hooks = Hooks()) -> Decision:
    """Search, choose and gate (module docstring). Raises ``TuneInterrupted`` when ``hooks.stop`` is set
    (every finished evaluation is in the store), ``ConfigError`` / ``UavDepthError`` on bad input."""
    config = request.config
    metric = config.metric
    fitness = FITNESS[metric]
    hooks.phase(f"loading the frames of {request.logdir}")
    k = parse_folds(request.folds, len(find_sessions(request.logdir)), request.holdout)
    folds = (load_folds(request.logdir, k, fitness.needs) if k > 1
             else [load_split(request.logdir, request.holdout, fitness.needs)])
    names_k = set_names(k)
    framesets: dict[str, FrameSet] = {}
    for (tn, hn), (tr, ho) in zip(names_k, folds):
        framesets[tn], framesets[hn] = tr, ho
    tuned_keys = [d["key"] for d in describe_space(make_space(config.optimizer, config.keys))["dims"]]
    direction = "minimize" if fitness.direction < 0 else "maximize"
    stores = [RunStore(request.store_path, direction, tuned_keys, study_name=fold_study_name(j)) for j in range(k)]
    screen = _screen(request, framesets["train"], hooks)
    try:
        executor = make_executor(framesets, metric, request.workers, request.ray_address)
        try:
            hooks.begin(k * (config.runs * config.budget + 1))
            deadline = None if request.timeout_s is None else time.monotonic() + request.timeout_s
            studies, results, selections, budget = [], [], [], None
            for j, ((tn, hn), (tr, ho), st) in enumerate(zip(names_k, folds, stores)):
                left = None if deadline is None else max(1e-3, deadline - time.monotonic())
                study_j = Study(config, tr, executor, st, request.base, progress=hooks.progress, stop=hooks.stop,
                                timeout_s=left, frameset=tn)
                study_j.open(request.resume)
                result_j = study_j.run()
                if j == k - 1:
                    hooks.searched()
                result_j.best_params()        # raises when every candidate failed
                studies.append(study_j)
                results.append(result_j)
                if request.max_ms is not None:
                    hooks.phase(f"re-timing the search front under --max-ms {request.max_ms:g}")
                    choice = choose_under_budget(st, metric, tr, request.max_ms)
                    if j == 0:
                        budget = {"max_ms": request.max_ms, "front": choice.front,
                                  "chosen": None if choice.params is None else
                                  {"value": choice.value, "ms": choice.ms, "params": choice.params.to_dict()},
                                  "reason": choice.reason}
                    candidates = [] if choice.params is None else [(choice.params.to_dict(), choice.value)]
                else:
                    candidates = top_candidates(st, metric, SELECT_POOL)
                fold = f" (fold {j + 1} of {k})" if k > 1 else ""
                hooks.phase(f"choosing among the best candidates on the {len(ho)} held-out frame(s){fold}"
                            if len(ho) else "choosing among the best candidates on the training frames")
                selections.append(select(hooks.count(executor, "candidates scored"), metric, request.base,
                                         result_j.baseline.value, candidates, bool(len(ho)), train_set=tn,
                                         holdout_set=hn, nudge_keys=tuned_keys,
                                         screen=screen.reject if screen.active else None))
            cross = None
            if k > 1:
                hooks.phase(f"scoring the {k} fold winners on every fold's held-out sessions")
                cross = cross_select(hooks.count(executor, "candidates scored"), metric, request.base, selections,
                                     [hn for _, hn in names_k])
                selection = _pooled_selection(fitness, request.base, results[0], selections, cross)
            else:
                selection = selections[0]
            chosen = params_from_dict(selection.chosen["params"])
            names = [n for n in ("train", "holdout") if len(framesets[n])]
            own, cv_sets = farther_sets(k, selection, cross, names_k, framesets)
            hooks.phase("scoring the base and the chosen parameters with every metric on " + " and ".join(names))
            counted = hooks.count(executor, "scored")
            convention = default_convention(metric)
            scores = full_scores(counted, [request.base, chosen], names + [n for n in own if n not in names],
                                 convention)
            cv_farther = None
            if cv_sets:
                # the cross-validated view: each fold's own winner on its own held-out sessions, base beside it
                # (one batch, so a pool of workers scores the pairs side by side)
                pairs = ([(request.base, hn) for _, hn in cv_sets]
                         + [(params_from_dict(selections[j].chosen["params"]), hn) for j, hn in cv_sets])
                evs = run_all(counted, [Task(p.to_dict(), hn, full=True, convention=convention) for p, hn in pairs])
                cv_farther = farther_check(evs[:len(cv_sets)], evs[len(cv_sets):], "cross-validated held-out")
            points = [(ev.ms, ev.value) for _, p, ev in stores[0].evaluations() if ev.ok and math.isfinite(ev.ms)]
            front = search_front(stores[0], metric)
            kind, workers = executor.kind, executor.workers
        finally:
            executor.close()
    finally:
        for st in stores:
            st.close()
    where = ("held-out" if selection.on == "holdout" else "training") + (
        f" (fold {cross.pool[cross.winner]['fold'] + 1}'s own)" if cross is not None and cross.winner is not None
        else "")
    farther = farther_check([scores[(0, n)] for n in own], [scores[(1, n)] for n in own], where)
    safety = screen.check(chosen)
    beats = selection.beats_base and (cross is None or fitness.utility(cross.cv_tuned) > fitness.utility(cross.cv_base))
    blocked = f"--max-ms: {budget['reason']}" if budget and budget["reason"] else None
    screened = sum(str(r.get("fragile") or "").startswith(UNSAFE) for sel in selections for r in sel.rows)
    refused = None if blocked else _refusal(metric, k, selection, cross, folds[0][1], beats, farther, cv_farther,
                                            safety, screened)
    return Decision(request, k, framesets, names, studies[0], results[0], selection, selections, folds, cross,
                    chosen, selection.chosen["train"], scores, beats, farther, cv_farther, budget, front, refused,
                    blocked, kind, workers, points, safety)


def _screen(request: TuneRequest, train: FrameSet, hooks: Hooks) -> SafetyScreen:
    return SafetyScreen(request.safety, request.base, train, hooks.phase)


def _pooled_selection(fitness, base: StereoParams, result: StudyResult, selections: list[Selection],
                      cross: CrossSelection) -> Selection:
    """The k-fold choice as one Selection: the base (its cross-validated held-out value) and each pooled fold
    winner (its mean over every fold's held-out sessions, for the report), the winner ``cross.winner`` (the largest
    gain over the base on its own fold's held-out sessions)."""
    rows = [{"params": base.to_dict(), "train": result.baseline.value, "holdout": cross.cv_base, "fragile": None}]
    rows += [{"params": p["params"], "train": selections[p["fold"]].chosen["train"], "holdout": p["mean"],
              "fragile": None, "fold": p["fold"] + 1, "holdout_per_fold": p["holdout"]} for p in cross.pool]
    for r in rows:
        r["train_utility"], r["holdout_utility"] = fitness.utility(r["train"]), fitness.utility(r["holdout"])
    return Selection(rows, 0 if cross.winner is None else cross.winner + 1, "holdout")


def farther_sets(k: int, selection: Selection, cross: CrossSelection | None, names_k: list[tuple[str, str]],
                  framesets: dict[str, FrameSet]) -> tuple[list[str], list[tuple[int, str]]]:
    """Where the gate's farther check counts: only frames the candidate did not train on.

    Returns (the chosen candidate's frame sets, [(fold, held-out set)] of the cross-validated view). One split:
    the frames the choice was made on. k folds: the pooled winner's own fold's held-out sessions (it trained on
    every other fold's), none when no fold winner beat the base (the base is kept); the cross-validated view:
    every fold's held-out sessions, each scored with that fold's own winner."""
    if cross is None:
        name = "holdout" if selection.on == "holdout" else "train"
        return [name] if len(framesets[name]) else [], []
    own = [] if cross.winner is None else [names_k[cross.pool[cross.winner]["fold"]][1]]
    return [n for n in own if len(framesets[n])], [(j, hn) for j, (_, hn) in enumerate(names_k) if len(framesets[hn])]


def _refusal(metric: str, k: int, selection: Selection, cross: CrossSelection | None, holdout: FrameSet,
             beats: bool, farther: FartherCheck, cv_farther: FartherCheck | None,
             safety: FartherCheck | None = None, screened: int = 0) -> str | None:
    """The gate's one line, or None when the chosen parameters may replace the base. ``screened``: candidates
    the safety sweep set aside during the choice (said when nothing else beat the base)."""
    reasons = []
    if not beats and screened:
        reasons.append(f"{screened} candidate(s) that beat the base on held-out frames failed the safety sweep "
                       f"(report: table.md)")
    if not beats:
        if cross is not None:
            reasons.append(f"the tuned parameters do not beat the base on the held-out sessions of {k} folds "
                           f"({metric} cross-validated {cross.cv_tuned:.4g} vs base {cross.cv_base:.4g}; chosen, "
                           f"mean held-out {selection.chosen['holdout']:.4g} vs {selection.base['holdout']:.4g})")
        else:
            where = (f"the {len(holdout)} held-out frame(s)" if selection.on == "holdout"
                     else "the training frames (no held-out frame)")
            reasons.append(f"the tuned parameters do not beat the base on {where} ({metric} "
                           f"{selection.chosen[selection.on]:.4g} vs base {selection.base[selection.on]:.4g})")
    # reading farther than the branch is refused like a worse score
    reasons += [c.reason for c in (farther, cv_farther, safety) if c is not None and c.reason]
    return "; ".join(reasons) if reasons else None
