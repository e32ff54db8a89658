"""Genetic algorithms: the paper's, and a real-coded one for the improved space.

The variation operators are DEAP's (``cxTwoPoint``, ``mutUniformInt``,
``cxSimulatedBinaryBounded``, ``mutPolynomialBounded``, ``selTournament``,
``selBest``), wrapped as small strategy objects so a GA is assembled from them.
DEAP's operators draw from Python's global ``random`` module; here they draw
from a private ``random.Random`` seeded from the run's numpy Generator
(:func:`private_random` points DEAP's operator modules at it for the duration
of one call, under a lock, and puts the global back). DEAP's ``creator`` (a
global class registry) is not used: an individual is a plain list with a
``fitness`` attribute holding a larger-is-better float.
"""

from __future__ import annotations

import random
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import numpy as np
from deap import tools
from deap.tools import crossover as _cx
from deap.tools import mutation as _mut
from deap.tools import selection as _sel

_DEAP_MODULES = (_cx, _mut, _sel)
_LOCK = threading.Lock()


@contextmanager
def private_random(rnd: random.Random) -> Iterator[None]:
    """Make DEAP's operators draw from ``rnd`` inside the block (the global ``random`` is untouched)."""
    with _LOCK:
        saved = [m.random for m in _DEAP_MODULES]
        for m in _DEAP_MODULES:
            m.random = rnd
        try:
            yield
        finally:
            for m, r in zip(_DEAP_MODULES, saved):
                m.random = r


class Individual(list):
    """A genome as DEAP's operators expect it: a mutable sequence; ``fitness`` larger is better."""

    fitness: float = float("-inf")


# -- strategies ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TwoPointCrossover:
    """The paper's crossover: two-point, applied to a pair with probability ``prob``."""

    prob: float = 0.6

    def __call__(self, a: list, b: list, rnd: random.Random) -> None:
        if rnd.random() < self.prob:
            with private_random(rnd):
                tools.cxTwoPoint(a, b)


@dataclass(frozen=True)
class UniformIntMutation:
    """The paper's mutation: each gene replaced with probability ``indpb`` by a uniform integer low..up."""

    low: int = 1
    up: int = 10
    indpb: float = 0.3

    def __call__(self, ind: list, rnd: random.Random) -> None:
        with private_random(rnd):
            tools.mutUniformInt(ind, self.low, self.up, self.indpb)


@dataclass(frozen=True)
class SBXCrossover:
    """Simulated binary crossover on [low, up] genes (Deb), applied with probability ``prob``."""

    prob: float = 0.9
    eta: float = 15.0
    low: float = 0.0
    up: float = 1.0

    def __call__(self, a: list, b: list, rnd: random.Random) -> None:
        if rnd.random() < self.prob:
            with private_random(rnd):
                tools.cxSimulatedBinaryBounded(a, b, self.eta, self.low, self.up)


@dataclass(frozen=True)
class PolynomialMutation:
    """Bounded polynomial mutation (Deb); ``indpb`` None means 1 / genome length."""

    eta: float = 20.0
    indpb: float | None = None
    low: float = 0.0
    up: float = 1.0

    def __call__(self, ind: list, rnd: random.Random) -> None:
        with private_random(rnd):
            tools.mutPolynomialBounded(ind, self.eta, self.low, self.up, self.indpb or 1.0 / len(ind))


@dataclass(frozen=True)
class TournamentSelection:
    """Parents by tournaments of ``size`` (the paper does not say; tournament of 3 is DEAP's usual)."""

    size: int = 3

    def __call__(self, pop: list[Individual], k: int, rnd: random.Random) -> list[Individual]:
        with private_random(rnd):
            return tools.selTournament(pop, k, self.size)


def select_best(pop: list[Individual], k: int) -> list[Individual]:
    """The ``k`` fittest, ties kept in population order (stable sort)."""
    return tools.selBest(pop, k)


# -- the algorithm ------------------------------------------------------------------------------------------------

class GeneticAlgorithm:
    """Generational GA with elitism, proposing one generation per :meth:`ask`.

    Generation 0 is ``initial`` (completed with samples of ``space``). Each next
    generation: the ``elite`` fittest carried unchanged, then
    ``population - elite`` children: parents by ``selection``, cloned, paired in
    order and crossed with ``crossover``, every child passed to ``mutation``.
    """

    def __init__(self, space: Any, population: int, rng: np.random.Generator, crossover, mutation,
                 selection=TournamentSelection(), elite: int = 5, initial: Sequence[Sequence[float]] = (),
                 dtype: type = float):
        if not 0 <= elite < population:
            raise ValueError(f"elite must be in 0..population-1, got {elite} for population {population}")
        self.space, self.n, self.elite = space, population, elite
        self.crossover, self.mutation, self.selection = crossover, mutation, selection
        self.dtype = dtype
        # one private stream for DEAP's operators, seeded from the run's Generator
        self.rnd = random.Random(int(rng.integers(0, 2**63 - 1)))
        init = [Individual(self.dtype(x) for x in g) for g in list(initial)[:population]]
        while len(init) < population:
            init.append(Individual(self.dtype(x) for x in space.sample(rng)))
        self.pop: list[Individual] = init
        self._evaluated = False

    def ask(self) -> list[list]:
        if self._evaluated:
            self.pop = self._next_generation()
            self._evaluated = False
        return [list(ind) for ind in self.pop]

    def tell(self, utilities: Sequence[float]) -> None:
        for ind, u in zip(self.pop, utilities):
            ind.fitness = float(u)
        self._evaluated = True

    def _next_generation(self) -> list[Individual]:
        elites = [self._clone(i) for i in select_best(self.pop, self.elite)]
        parents = self.selection(self.pop, self.n - self.elite, self.rnd)
        children = [self._clone(p) for p in parents]
        for a, b in zip(children[0::2], children[1::2]):
            self.crossover(a, b, self.rnd)
        for c in children:
            self.mutation(c, self.rnd)
            if self.dtype is int:  # DEAP keeps ints; guard the dtype for the decoder
                c[:] = [int(x) for x in c]
        return elites + children

    @staticmethod
    def _clone(ind: Individual) -> Individual:
        c = Individual(ind)
        c.fitness = ind.fitness
        return c
