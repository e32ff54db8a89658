"""A tuning study: runs of an optimiser, every evaluation cached and stored.

Roles (as in Optuna): the optimiser proposes genomes, the space turns them into
candidates validated by the daemon's schema, the executor evaluates, the store
persists. A study is ``runs`` independent runs; run ``i`` draws its randomness
from ``SeedSequence(seed).spawn(runs)[i]``, so each run's result depends only on
(seed, i, data), never on the number of workers or on what was cached.

Identical candidates are evaluated once: each is keyed by a hash of its
parameters, the frames' digest, the fitness and :data:`EVAL_VERSION`; elites and
re-proposed parameter sets are answered from that cache (memory, then the run
store), which is also how ``--resume`` replays a killed run to the very same end.

Longer than 400 lines because the study's loop, its held-out choice and its resume are one orchestration over the store.
"""

from __future__ import annotations

import hashlib
import json
import math
import statistics
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.errors import ConfigError, UavDepthError
from uav_depth.core.params import OPENCV_COST_MAX, StereoParams, params_from_dict

from uav_depth.tuning.executor import Executor, run_all
from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.objective import FITNESS, OK, Evaluation, Task, failed
from uav_depth.tuning.optimizers import OPTIMIZERS, make_space
from uav_depth.tuning.space import WINNABLE_COST_MAX, describe_space
from uav_depth.tuning.store import RunStore

#: Bump when the meaning of an evaluation changes: old cached evaluations are then not reused.
#: 2: candidates with a compute.roi are scored inside it (1 counted the unanswered rest as errors).
EVAL_VERSION = 2


class TuneInterrupted(UavDepthError):
    """The run was stopped (Ctrl-C / SIGTERM); finished evaluations are in the store."""


@dataclass(frozen=True)
class StudyConfig:
    """Everything that determines a study's result (workers and time budgets do not)."""

    metric: str = "flown"
    optimizer: str = "tpe"
    population: int = 30
    generations: int = 100
    runs: int = 1
    seed: int = 0
    keys: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.metric not in FITNESS:
            raise ConfigError("--metric", f"must be one of {', '.join(FITNESS)}", self.metric)
        if self.optimizer not in OPTIMIZERS:
            raise ConfigError("--optimizer", f"must be one of {', '.join(OPTIMIZERS)}", self.optimizer)
        for key, value, lo in (("--population", self.population, 2), ("--generations", self.generations, 1),
                               ("--runs", self.runs, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise ConfigError(key, f"must be an integer of at least {lo}", value)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError("--seed", "must be a non-negative integer", self.seed)

    @property
    def budget(self) -> int:
        """Proposals per run (the equal-budget unit between optimisers)."""
        return self.population * self.generations


@dataclass
class RunResult:
    """One run: its best candidate and the best-so-far fitness after each generation."""

    run: int
    best_key: str | None = None
    best_params: dict[str, Any] | None = None
    best_value: float = math.nan
    best_utility: float = -math.inf
    history: list[float] = field(default_factory=list)
    proposals: int = 0
    evaluated: int = 0      # distinct candidates this run evaluated for the first time
    failed: int = 0         # proposals that were failed candidates


@dataclass
class StudyResult:
    config: StudyConfig
    runs: list[RunResult]
    baseline: Evaluation
    evaluated: int          # evaluations computed in this invocation
    cached: int             # proposals answered from the cache / store
    wall_s: float
    timed_out: bool = False  # --timeout stopped it before its last generation

    @property
    def best(self) -> RunResult:
        """The run with the best training fitness (first of equals)."""
        return max(self.runs, key=lambda r: r.best_utility)

    def best_params(self) -> StereoParams:
        """The best run's parameters; raises when every candidate of every run failed."""
        if self.best.best_params is None:
            raise UavDepthError(f"every candidate failed ({sum(r.proposals for r in self.runs)} proposals): "
                                "no parameters to write; see the failures' reasons in the run store")
        return params_from_dict(self.best.best_params)


def candidate_key(params: Mapping[str, Any], frames_digest: str, metric: str) -> str:
    blob = json.dumps({"p": params, "f": frames_digest, "m": metric, "v": EVAL_VERSION}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


class Study:
    """Runs ``config`` on ``train`` frames through ``executor``, caching in ``store``."""

    def __init__(self, config: StudyConfig, train: FrameSet, executor: Executor, store: RunStore,
                 base: StereoParams, progress: Callable[[int, float], None] | None = None,
                 stop: threading.Event | None = None, timeout_s: float | None = None, frameset: str = "train"):
        self.config, self.train, self.executor, self.store, self.base = config, train, executor, store, base
        self.frameset = frameset      # the executor's name of ``train`` (a fold's training set: "train1" ...)
        self.timeout_s = timeout_s
        self._deadline = math.inf
        self.timed_out = False
        self.fitness = FITNESS[config.metric]
        self.space = make_space(config.optimizer, config.keys)
        self.digest = train.digest()
        self.progress = progress or (lambda n, best: None)
        self.stop = stop or threading.Event()
        self._memo: dict[str, Evaluation] = {}
        self.evaluated = 0
        self.cached = 0

    # -- identity and resume ------------------------------------------------------------------------------------

    def identity(self) -> dict[str, Any]:
        """What a resumed run must share with the stored one.

        Not the number of generations or runs: generation g of run i depends only on
        (seed, i, the generations before it), so a resumed study may be extended."""
        return {"metric": self.config.metric, "optimizer": self.config.optimizer,
                "population": self.config.population, "seed": self.config.seed, "space": describe_space(self.space),
                "frames": self.digest, "frame_keys": self.train.keys, "base": self.base.to_dict(),
                "eval_version": EVAL_VERSION}

    def open(self, resume: bool) -> None:
        """Record this study in the store, or check it matches the stored one on ``resume``."""
        ident = json.loads(json.dumps(self.identity(), default=str))
        stored = self.store.config()
        if stored is None:
            self.store.set_config(ident)
            return
        if not resume:
            raise ConfigError("--store", "already holds a tuning run: pass --resume to continue it, "
                              "or choose another --store", self.store.path)
        for key in ident:
            if stored.get(key) != ident[key]:
                raise ConfigError(f"--resume ({key})", "must match the stored run",
                                  f"{_short(ident[key])} (stored: {_short(stored.get(key))})")
        self.store.set_config(ident)

    # -- evaluation ---------------------------------------------------------------------------------------------

    def _lookup(self, key: str) -> Evaluation | None:
        ev = self._memo.get(key)
        if ev is None:
            ev = self.store.get(key)
            if ev is not None:
                self._memo[key] = ev
        return ev

    def evaluate(self, candidates: Sequence[tuple[str, dict[str, Any], Evaluation | None]]) -> list[Evaluation]:
        """Evaluations of (key, params, known) candidates, computing each missing key once."""
        out: list[Evaluation | None] = [None] * len(candidates)
        todo: dict[str, tuple[dict[str, Any], list[int]]] = {}
        for i, (key, params, known) in enumerate(candidates):
            ev = known or self._lookup(key)
            if ev is not None:
                if known is not None and key not in self._memo:
                    self._memo[key] = known
                    self.store.put(key, params, None, known)
                out[i] = ev
                continue
            todo.setdefault(key, (params, []))[1].append(i)
        n_cached = sum(1 for o in out if o is not None)
        self.cached += n_cached
        if n_cached:
            self.progress(n_cached, math.nan)
        keys = list(todo)
        tasks = [Task(todo[k][0], self.frameset) for k in keys]   # every executor starts nothing once stop is set
        for j, ev in self.executor.imap(tasks, self.stop):
            key = keys[j]
            params, idx = todo[key]
            self.store.put(key, params, params_from_dict(params).hash(), ev)
            self._memo[key] = ev
            self.evaluated += 1
            for i in idx:
                out[i] = ev
            self.progress(len(idx), ev.value if ev.ok else math.nan)
        if any(o is None for o in out):
            raise self.interrupted()
        return out  # type: ignore[return-value]

    def interrupted(self) -> TuneInterrupted:
        return TuneInterrupted(f"interrupted: {self.store.count()} evaluations are kept in {self.store.path}; "
                               "run the same command with --resume to continue")

    def candidate(self, genome: Sequence[float]) -> tuple[str, dict[str, Any], Evaluation | None]:
        """(cache key, parameter dict, a failed Evaluation if the schema rejects it)."""
        changes = self.space.decode(genome, self.base)
        try:
            params = self.base.replace(**changes).to_dict()
        except ConfigError as exc:
            rejected = {"changes": changes, "invalid": True}
            return candidate_key(rejected, self.digest, self.config.metric), rejected, failed(self.fitness, str(exc))
        return candidate_key(params, self.digest, self.config.metric), params, None

    def baseline(self) -> Evaluation:
        params = self.base.to_dict()
        return self.evaluate([(candidate_key(params, self.digest, self.config.metric), params, None)])[0]

    # -- the loop -----------------------------------------------------------------------------------------------

    def run_one(self, run: int, seed_seq: np.random.SeedSequence) -> RunResult:
        rng = np.random.default_rng(seed_seq)
        opt = OPTIMIZERS[self.config.optimizer].factory(self.space, self.config.population, rng, self.base)
        res = RunResult(run)
        for gen in range(self.config.generations):
            if self.stop.is_set():
                raise self.interrupted()
            if (gen > 0 or run > 0) and time.monotonic() > self._deadline:
                self.timed_out = True     # the first generation always runs: there is a result to report
                break
            genomes = opt.ask()
            cands = [self.candidate(g) for g in genomes]
            before = self.evaluated
            evs = self.evaluate(cands)
            utilities = [self.fitness.utility(ev.value) if ev.ok else -math.inf for ev in evs]
            opt.tell(utilities)
            self.store.put_trials(run, gen, [c[0] for c in cands], utilities)
            for (key, params, _), ev, u in zip(cands, evs, utilities):
                res.proposals += 1
                res.failed += 0 if ev.ok else 1
                if u > res.best_utility:
                    res.best_utility, res.best_key, res.best_params, res.best_value = u, key, params, ev.value
            res.evaluated += self.evaluated - before
            res.history.append(res.best_value)
        return res

    def run(self) -> StudyResult:
        """Every run; with ``timeout_s``, no generation but the first starts after it (each one started is finished, so
        what was evaluated is a prefix of the full study and ``--resume`` continues it exactly)."""
        t0 = time.perf_counter()
        if self.timeout_s is not None:
            self._deadline = time.monotonic() + self.timeout_s
        baseline = self.baseline()
        seeds = np.random.SeedSequence(self.config.seed).spawn(self.config.runs)
        runs = []
        for i, s in enumerate(seeds):
            run = self.run_one(i, s)
            if run.proposals:
                runs.append(run)
            if self.timed_out:
                break
        return StudyResult(self.config, runs, baseline, self.evaluated, self.cached, time.perf_counter() - t0,
                           self.timed_out)


def _short(value: Any) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


# -- after the search: held-out scores, Pareto front, time budget -------------------------------------------------

def full_scores(executor: Executor, params: Sequence[StereoParams], framesets: Sequence[str],
                convention: str | None = None) -> dict:
    """Every metric (in ``convention``) of each params on each named frame set: {(i, set): Evaluation}."""
    tasks, index = [], []
    for i, p in enumerate(params):
        for name in framesets:
            tasks.append(Task(p.to_dict(), name, full=True, convention=convention))
            index.append((i, name))
    return dict(zip(index, run_all(executor, tasks)))


def pareto_front(points: Sequence[tuple[float, float, Any]]) -> list[tuple[float, float, Any]]:
    """Non-dominated (utility, ms, item) points (larger utility, smaller ms), fastest first."""
    front: list[tuple[float, float, Any]] = []
    best = -math.inf
    for u, ms, item in sorted(points, key=lambda p: (p[1], -p[0])):
        if u > best:
            front.append((u, ms, item))
            best = u
    return front


def search_front(store: RunStore, fitness_name: str) -> list[dict[str, Any]]:
    """Pareto front of (fitness, ms per frame) over every stored evaluation, with the search's own timings."""
    fitness = FITNESS[fitness_name]
    pts = [(fitness.utility(ev.value), ev.ms, (key, ev)) for key, params, ev in store.evaluations()
           if ev.status == OK and math.isfinite(ev.ms) and not params.get("invalid")]
    return [{"key": key, "value": ev.value, "ms": ms} for _, ms, (key, ev) in pareto_front(pts)]


def time_params(params: StereoParams, frames: FrameSet, repeats: int = 3) -> float:
    """Median over ``repeats`` of the mean ms per frame of what flies (``flight_pipeline``: no WLS
    smoothing), in this process with OpenCV's default threads (how the daemon runs it)."""
    pipe = flight_pipeline(params)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for f in frames.frames:
            pipe.run(f.left, f.right)
        samples.append((time.perf_counter() - t0) * 1000.0 / max(1, len(frames)))
    return float(statistics.median(samples))


@dataclass(frozen=True)
class BudgetChoice:
    params: StereoParams | None
    value: float
    ms: float
    front: list[dict[str, Any]]
    reason: str | None = None


def choose_under_budget(store: RunStore, fitness_name: str, frames: FrameSet, max_ms: float,
                        max_points: int = 12) -> BudgetChoice:
    """The best stored candidate whose re-timed frame time is within ``max_ms``.

    The search's own timings come from busy workers and are only a guide: the
    Pareto front of (fitness, ms) over every stored evaluation is re-timed here,
    side by side, and the choice is made on those times.
    """
    fitness = FITNESS[fitness_name]
    pts = [(fitness.utility(ev.value), ev.ms, (key, params, ev)) for key, params, ev in store.evaluations()
           if ev.status == OK and math.isfinite(ev.ms) and not params.get("invalid")]
    front = pareto_front(pts)
    if len(front) > max_points:  # keep the extremes and an even spread between
        idx = np.unique(np.linspace(0, len(front) - 1, max_points).round().astype(int))
        front = [front[i] for i in idx]
    timed = []
    for u, ms, (key, params, ev) in front:
        p = params_from_dict(params)
        timed.append({"key": key, "value": ev.value, "search_ms": ms, "ms": time_params(p, frames), "params": params})
    fits = [t for t in timed if t["ms"] <= max_ms]
    if not fits:
        fastest = min((t["ms"] for t in timed), default=math.nan)
        return BudgetChoice(None, math.nan, math.nan, timed,
                            f"no evaluated candidate runs within {max_ms:g} ms per frame (fastest {fastest:.0f} ms)")
    best = max(fits, key=lambda t: fitness.utility(t["value"]))
    return BudgetChoice(params_from_dict(best["params"]), best["value"], best["ms"], timed)


# -- the choice: on frames the search did not see ------------------------------------------------------------------

#: How many of the best training candidates the held-out choice is among (study.select): the best SELECT_TOP
#: that may win; each one set aside (fragile, or refused by the safety sweep) is replaced by the next best.
SELECT_TOP = 6
#: How deep in the training ranking those replacements may go (tune passes this many to study.select).
SELECT_POOL = 30


def fragile_reason(params: StereoParams) -> str | None:
    """Why ``params`` may not win however well it scored (a cliff near it), or None."""
    for name in ("p1", "p2"):
        value = getattr(params.sgbm, name)
        if value > WINNABLE_COST_MAX:       # the same bound the improved space searches up to
            return (f"sgbm.{name}={value} is above {WINNABLE_COST_MAX}, half of OpenCV's 16-bit cost limit "
                    f"{OPENCV_COST_MAX} (fragile: costs wrap near it)")
    return None


@dataclass(frozen=True)
class Selection:
    """The winner chosen on held-out frames among the best training candidates.

    ``rows``: one per candidate scored (the base first): params dict, train value,
    held-out value (NaN without held-out frames), fragile reason. ``winner``: index
    into rows of the best candidate other than the base that is not fragile (0 when
    there is none); ``on``: "holdout" or "train" (the frames the choice was made on).
    """

    rows: list[dict[str, Any]]
    winner: int
    on: str

    @property
    def chosen(self) -> dict[str, Any]:
        return self.rows[self.winner]

    @property
    def base(self) -> dict[str, Any]:
        return self.rows[0]

    @property
    def beats_base(self) -> bool:
        """The winner is not the base and scores strictly better than it on the choice's frames."""
        key = self.on
        return self.winner != 0 and self.chosen[f"{key}_utility"] > self.base[f"{key}_utility"]


def top_candidates(store: RunStore, fitness_name: str, n: int = SELECT_TOP) -> list[tuple[dict[str, Any], float]]:
    """The ``n`` best distinct (params, train value) of every stored evaluation, best first."""
    fitness = FITNESS[fitness_name]
    rows = [(fitness.utility(ev.value), i, params, ev.value) for i, (_, params, ev) in enumerate(store.evaluations())
            if ev.status == OK and not params.get("invalid")]
    rows.sort(key=lambda r: (-r[0], r[1]))
    return [(params, value) for _, _, params, value in rows[:n]]


def select(executor: Executor, fitness_name: str, base: StereoParams, base_train: float,
           candidates: Sequence[tuple[dict[str, Any], float]], have_holdout: bool, *,
           train_set: str = "train", holdout_set: str = "holdout",
           nudge_keys: Sequence[str] | None = None,
           screen: Callable[[dict[str, Any]], str | None] | None = None,
           top: int = SELECT_TOP) -> Selection:
    """Score the base and the best ``top`` of ``candidates`` (best training value first) on the held-out frames;
    the best one that is not set aside wins.

    Set aside: fragile, i.e. P1/P2 near the cost limit (:func:`fragile_reason`), or, with ``nudge_keys``, a
    one-step nudge of one of those keys on the training frames loses the candidate's whole gain over the base
    (``robust.nudge_check``; checked only for a candidate about to win, then the next is tried). ``screen``:
    another check of a candidate about to win that beats the base, returning why it may not (the tuner's
    safety sweep, ``safety.SafetyScreen.reject``) or None; a rejected one is set aside the same way.
    Each candidate set aside is replaced by the next one of ``candidates`` (scored on the held-out frames too),
    so the choice is always among ``top`` candidates that may win: a screen that refuses the best ones does not
    narrow it to the rest of a fixed list, and the held-out frames never choose among more than ``top``.
    Without held-out frames the choice falls back to the training value (reports say so).
    Ties keep the earlier row (the base first, then the better training value).
    """
    from uav_depth.tuning.robust import nudge_check

    fitness = FITNESS[fitness_name]
    rows = [{"params": base.to_dict(), "train": base_train}]
    reserve = [(params, value) for params, value in candidates if params != rows[0]["params"]]
    on = "holdout" if have_holdout else "train"

    def score(new: list[dict[str, Any]]) -> None:
        held = run_all(executor, [Task(r["params"], holdout_set) for r in new]) if have_holdout else [None] * len(new)
        for r, ev in zip(new, held):
            r["holdout"] = math.nan if ev is None else (ev.value if ev.ok else fitness.worst)
            r["fragile"] = fragile_reason(params_from_dict(r["params"]))
            r["train_utility"] = fitness.utility(r["train"])
            r["holdout_utility"] = fitness.utility(r["holdout"])

    def fill() -> None:
        """Score more candidates until ``top`` of them may win, or none is left."""
        while reserve and (need := top - sum(r["fragile"] is None for r in rows[1:])) > 0:
            new = [{"params": params, "train": value} for params, value in reserve[:need]]
            del reserve[:need]
            score(new)
            rows.extend(new)

    score(rows)
    fill()
    winner = 0
    while True:     # the best row not set aside yet (ranked again each time: a newcomer may rank anywhere)
        i = min((i for i in range(1, len(rows)) if rows[i]["fragile"] is None),
                key=lambda i: (-rows[i][f"{on}_utility"], i), default=None)
        if i is None:
            break
        r = rows[i]
        beats = r[f"{on}_utility"] > rows[0][f"{on}_utility"]
        if nudge_keys and beats:
            check = nudge_check(executor, fitness_name, params_from_dict(r["params"]), r["train"], base_train,
                                nudge_keys, train_set)
            r["nudges"] = check.values
            r["fragile"] = check.reason
        if r["fragile"] is None and screen is not None and beats:
            r["fragile"] = screen(r["params"])
        if r["fragile"] is None:
            winner = i
            break
        fill()
    return Selection(rows, winner, on)


def result_summary(result: StudyResult) -> dict[str, Any]:
    cfg = asdict(result.config)
    return {"config": cfg, "wall_s": result.wall_s, "evaluated": result.evaluated, "cached": result.cached,
            "baseline": {"value": result.baseline.value, "status": result.baseline.status,
                         "reason": result.baseline.reason},
            "runs": [{"run": r.run, "best_value": r.best_value, "best_key": r.best_key,
                      "best_params": r.best_params, "history": r.history, "proposals": r.proposals,
                      "evaluated": r.evaluated, "failed": r.failed} for r in result.runs],
            "best_run": result.best.run, "timed_out": result.timed_out}
