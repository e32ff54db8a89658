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

After the search, :mod:`.choice` chooses among the best candidates on frames the search did not see and
:mod:`.front` re-times the Pareto front under a frame-time budget.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from uav_depth.core.errors import ConfigError, UavDepthError
from uav_depth.core.params import StereoParams, params_from_dict
from uav_depth.core.ranging import RangingConfig

from uav_depth.tuning.executor import Executor
from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.objective import FITNESS, FLOWN_RANGING, Evaluation, Task, failed
from uav_depth.tuning.optimizers import OPTIMIZERS, make_space
from uav_depth.tuning.space import describe_space
from uav_depth.tuning.store import RunStore

#: Bump when the meaning of an evaluation changes: old cached evaluations are then not reused.
EVAL_VERSION = 3


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


def candidate_key(params: Mapping[str, Any], frames_digest: str, metric: str,
                  ranging: RangingConfig = FLOWN_RANGING, guide: str | None = None) -> str:
    """The cache key of one evaluation: the parameters, the frames, the fitness, the ranging settings it ranged
    with, the search guide it was read on (its ident, None: none) and :data:`EVAL_VERSION`."""
    doc = {"p": params, "f": frames_digest, "m": metric, "r": asdict(ranging), "v": EVAL_VERSION}
    if guide is not None:
        doc["g"] = guide
    blob = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


class Guide(Protocol):
    """What a study asks of a search guide (:class:`~uav_depth.tuning.guide.SearchGuide`)."""

    ident: str

    def read_base(self, executor: Executor, base: StereoParams, stop: threading.Event | None = None,
                  tick: Callable[[], None] = ...) -> None: ...

    def read_all(self, executor: Executor, candidates: Sequence[Mapping[str, Any]],
                 stop: threading.Event | None = None,
                 tick: Callable[[], None] = ...) -> list[dict[str, float] | str | None]: ...

    def constraints(self, ev: Evaluation) -> dict[str, float]: ...

    def feasible(self, ev: Evaluation) -> bool: ...


class Study:
    """Runs ``config`` on ``train`` frames through ``executor``, caching in ``store``.

    ``guide``: the search guide (:mod:`.guide`), whose frame sets the executor holds. For an optimiser that takes
    constraints (``OptimizerSpec.guided``: TPE) each candidate that beats the base and every candidate the guide
    passed in the generations before is read on it, its guide metrics are stored with its evaluation and are its
    constraints (feasible at 0 or less); the others search on the fitness alone and the guide is not read."""

    def __init__(self, config: StudyConfig, train: FrameSet, executor: Executor, store: RunStore,
                 base: StereoParams, progress: Callable[[int, float], None] | None = None,
                 stop: threading.Event | None = None, timeout_s: float | None = None, frameset: str = "train",
                 ranging: RangingConfig = FLOWN_RANGING, guide: Guide | None = None):
        self.config, self.train, self.executor, self.store, self.base = config, train, executor, store, base
        self.guide = guide if OPTIMIZERS[config.optimizer].guided else None
        self._guide_bar = math.inf    # the utility a candidate must beat to be read on the guide (Study.run sets it)
        self.ranging = ranging        # what the executor ranges with: part of every cache key
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
                "ranging": asdict(self.ranging), "eval_version": EVAL_VERSION,
                "guide": None if self.guide is None else self.guide.ident}

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

        def finish(i: int, ev: Evaluation) -> None:
            key = keys[i]
            params, idx = todo[key]
            self.store.put(key, params, params_from_dict(params).hash(), ev)
            self._memo[key] = ev
            self.evaluated += 1
            self.cached += len(idx) - 1       # the same candidate proposed again in this batch: answered once
            for n in idx:
                out[n] = ev
            self.progress(len(idx), ev.value if ev.ok else math.nan)

        tasks = [Task(todo[k][0], self.frameset) for k in keys]
        gained = []                  # the candidates to read on the guide, after the fitness of the whole batch
        for j, ev in self.executor.imap(tasks, self.stop):   # every executor starts nothing once stop is set
            if self._read_on_guide(ev):
                gained.append((j, ev))
            else:
                finish(j, ev)
        gained.sort(key=lambda g: g[0])                      # in proposal order: the same whatever the workers
        verdicts = self.guide.read_all(self.executor, [todo[keys[i]][0] for i, _ in gained], self.stop,
                                       lambda: self.progress(0, math.nan)) if gained else []
        for (i, ev), judged in zip(gained, verdicts):
            if judged is None:
                break
            finish(i, failed(self.fitness, judged, ev.seconds) if isinstance(judged, str)
                   else replace(ev, metrics={**ev.metrics, **judged}))
        if any(o is None for o in out):
            raise self.interrupted()
        return out  # type: ignore[return-value]

    def _read_on_guide(self, ev: Evaluation) -> bool:
        """Whether a candidate is read on the guide: it beats the base and every candidate the guide passed in the
        generations before (the base itself is read by the guide once)."""
        return self.guide is not None and ev.ok and self.fitness.utility(ev.value) > self._guide_bar

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
            return self.key(rejected), rejected, failed(self.fitness, str(exc))
        return self.key(params), params, None

    def key(self, params: Mapping[str, Any]) -> str:
        return candidate_key(params, self.digest, self.config.metric, self.ranging,
                             None if self.guide is None else self.guide.ident)

    def baseline(self) -> Evaluation:
        params = self.base.to_dict()
        return self.evaluate([(self.key(params), params, None)])[0]

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
            if self.guide is None:
                opt.tell(utilities)
            else:
                opt.tell(utilities, [self.guide.constraints(ev) for ev in evs])
                passed = [u for ev, u in zip(evs, utilities) if self.guide.feasible(ev)]
                self._guide_bar = max([self._guide_bar, *passed])
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
        if self.guide is not None:
            self.guide.read_base(self.executor, self.base, self.stop, lambda: self.progress(0, math.nan))
        baseline = self.baseline()
        if baseline.ok:
            self._guide_bar = self.fitness.utility(baseline.value)
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


def result_summary(result: StudyResult) -> dict[str, Any]:
    cfg = asdict(result.config)
    return {"config": cfg, "wall_s": result.wall_s, "evaluated": result.evaluated, "cached": result.cached,
            "baseline": {"value": result.baseline.value, "status": result.baseline.status,
                         "reason": result.baseline.reason},
            "runs": [{"run": r.run, "best_value": r.best_value, "best_key": r.best_key,
                      "best_params": r.best_params, "history": r.history, "proposals": r.proposals,
                      "evaluated": r.evaluated, "failed": r.failed} for r in result.runs],
            "best_run": result.best.run, "timed_out": result.timed_out}
