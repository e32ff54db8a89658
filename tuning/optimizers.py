"""Optimisers behind one ask/tell interface, in one name -> factory table.

An optimiser proposes one batch (a *generation*) of genomes per ``ask()`` and
receives their utilities (larger is better, -inf for a failed candidate) in
``tell()``. Every optimiser spends the same budget: ``generations`` batches of
``population`` proposals. Randomness comes only from the numpy Generator
handed in.

- ``ga-paper``: the paper's GA on the paper's 29 genes (faithful mode).
- ``ga``: a real-coded GA on the improved space, started from the base
  parameters.
- ``random``: uniform random search on the improved space (plus the base).
- ``tpe``: Optuna's tree-structured Parzen estimator on the improved space,
  its first generation the base and neighbours of it, led by the search
  guide (a constraint per proposal, :mod:`.guide`) when the tune has one.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from uav_depth.core.params import StereoParams

from uav_depth.tuning.paper_space import PaperSpace
from uav_depth.tuning.space import SchemaSpace, Space


class Optimizer(Protocol):
    def ask(self) -> list[list]: ...

    def tell(self, utilities: Sequence[float]) -> None: ...


#: The improved GA starts from the base and this fraction of the population drawn around it.
GA_LOCAL_FRACTION = 1 / 3
#: Spread (std, in unit gene space) of those neighbours.
GA_LOCAL_SIGMA = 0.1


def _ga():
    """The GA module, imported on use: it needs DEAP (the ``tuning`` extra), and merely listing the
    optimisers (``uav-depth --help`` on the drone's base install) must not."""
    from uav_depth.tuning import ga

    return ga


def paper_ga(space: Space, population: int, rng: np.random.Generator, base: StereoParams) -> Optimizer:
    """The paper: random start, two-point crossover 0.6, uniform integer mutation 0.3 per gene,
    top 5 carried over, parents by tournament of 3 (the paper does not say)."""
    ga = _ga()
    elite = min(5, population - 1)
    return ga.GeneticAlgorithm(space, population, rng, ga.TwoPointCrossover(0.6),
                               ga.UniformIntMutation(int(min(space.low)), int(max(space.up)), 0.3),
                               ga.TournamentSelection(3), elite=elite, dtype=int)


def local_start(space: Space, population: int, rng: np.random.Generator, base: StereoParams,
                fraction: float = GA_LOCAL_FRACTION) -> list[np.ndarray]:
    """The base's genome and ``population`` x ``fraction`` - 1 neighbours of it (sd GA_LOCAL_SIGMA): where the
    improved GA (a third) and TPE (the whole first generation) start. A shipped base is already good, and
    uniform samples of the whole space rarely beat it (bench/new_rig.py, the noisy 640x480 rig, 60 uniform
    genomes against 60 neighbours at sd 0.1 on 12 training frames: none of the uniform ones beat the flight
    file and 21 left a frame without a valid pixel; 19 of the neighbours beat it, every one of them on 16
    held-out frames too, and none failed)."""
    start = space.encode(base)
    return [start] + [np.clip(start + rng.normal(0.0, GA_LOCAL_SIGMA, start.shape), 0.0, 1.0)
                      for _ in range(max(0, int(population * fraction) - 1))]


def improved_ga(space: Space, population: int, rng: np.random.Generator, base: StereoParams) -> Optimizer:
    """Real-coded GA: the base and neighbours of it in the first generation, SBX crossover,
    polynomial mutation, tournament of 3, two elites."""
    ga = _ga()
    initial = local_start(space, population, rng, base)
    return ga.GeneticAlgorithm(space, population, rng, ga.SBXCrossover(0.9, 15.0), ga.PolynomialMutation(20.0),
                               ga.TournamentSelection(3), elite=min(2, population - 1), initial=initial,
                               dtype=float)


class RandomSearch:
    """Uniform samples of the space; the base first."""

    def __init__(self, space: Space, population: int, rng: np.random.Generator, base: StereoParams):
        self.space, self.n, self.rng = space, population, rng
        self.first = [space.encode(base)]

    def ask(self) -> list[list]:
        batch = [list(g) for g in self.first]
        self.first = []
        while len(batch) < self.n:
            batch.append(list(self.space.sample(self.rng)))
        return batch

    def tell(self, utilities: Sequence[float]) -> None:
        pass


#: Share of TPE's first generation that is the base and neighbours of it (all of it): its startup trials.
TPE_LOCAL_FRACTION = 1.0


class TPESearch:
    """Optuna's TPE (multivariate), asked a whole generation at a time. Its first generation is the base and
    neighbours of it (:func:`local_start`, TPE_LOCAL_FRACTION of the population), and they are its startup
    trials: the model starts from them, not from Optuna's default 10 uniform draws of the whole space, which
    at a small budget are a quarter of a fold's proposals spent where nothing beats a shipped base (measured:
    :func:`local_start`; the noisy 640x480 rig at 8 x 4 on the training sessions of two folds, seeds 0-5: 40
    proposals better than the base on them with this start, 15 with the base, one neighbour and 8 uniform
    draws, and 28 failed candidates against 50)."""

    def __init__(self, space: Space, population: int, rng: np.random.Generator, base: StereoParams):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self._fail = optuna.trial.TrialState.FAIL
        start = local_start(space, population, rng, base, TPE_LOCAL_FRACTION)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            sampler = optuna.samplers.TPESampler(seed=int(rng.integers(0, 2**31 - 1)), multivariate=True,
                                                 n_startup_trials=len(start))
        self.study = optuna.create_study(direction="maximize", sampler=sampler)
        self.names = [f"g{i:02d}" for i in range(space.size)]
        for genome in start:
            self.study.enqueue_trial(dict(zip(self.names, map(float, genome))))
        self.n = population
        self.trials: list = []

    def ask(self) -> list[list]:
        self.trials = [self.study.ask() for _ in range(self.n)]
        return [[t.suggest_float(name, 0.0, 1.0) for name in self.names] for t in self.trials]

    def tell(self, utilities: Sequence[float], constraints: Sequence[Mapping[str, float]] | None = None) -> None:
        """``constraints``: each proposal's, by name (the search guide's, Study; none for a proposal not read on
        it), feasible at 0 or less: TPE draws from the best feasible proposals and models the others apart."""
        for i, (t, u) in enumerate(zip(self.trials, utilities)):
            if math.isnan(u) or u == -math.inf:
                self.study.tell(t, state=self._fail)
                continue
            for name, value in (constraints[i] if constraints is not None else {}).items():
                t.set_constraint(name, value)
            self.study.tell(t, min(u, 1e300))


@dataclass(frozen=True)
class OptimizerSpec:
    name: str
    space: str  # "paper" or "schema"
    factory: Callable[[Space, int, np.random.Generator, StereoParams], Optimizer]
    doc: str
    #: Takes constraints in ``tell(utilities, constraints)``: the study reads the search guide for it.
    guided: bool = False


OPTIMIZERS: dict[str, OptimizerSpec] = {
    "ga-paper": OptimizerSpec("ga-paper", "paper", paper_ga, "the paper's GA on the paper's 29 genes (faithful)"),
    "ga": OptimizerSpec("ga", "schema", improved_ga, "real-coded GA on the improved space, from the base"),
    "random": OptimizerSpec("random", "schema", RandomSearch, "uniform random search on the improved space"),
    "tpe": OptimizerSpec("tpe", "schema", TPESearch, "Optuna TPE on the improved space, led by the search guide",
                         guided=True),
}


def make_space(optimizer: str, keys: Sequence[str] | None = None) -> Space:
    spec = OPTIMIZERS[optimizer]
    if spec.space == "paper":
        return PaperSpace()
    return SchemaSpace(tuple(keys)) if keys else SchemaSpace()


def describe(optimizer: str) -> dict[str, Any]:
    return {"name": optimizer, "space": OPTIMIZERS[optimizer].space, "doc": OPTIMIZERS[optimizer].doc}
