"""The search guide: sweep-like branches at the log's rig (``sim.sweep.search_guide``, 70 frames, rendered by the
caller as the safety sweep is) that TPE's candidates are read on while the search runs.

Why: on a rig no shipped file was made for, the fitness alone climbs into parameter sets that read more leafy
branches farther than the truth; the safety sweep then refuses every candidate the choice looks at and the tune
keeps its base, although sets both better and safe exist (docs/measurements/tuning-search-guide.md). The guide
tells the search where that region is. A candidate is *feasible* when it passes the safety sweep's two rules on
the guide's frames: no more frames read farther than the truth (by more than FARTHER_TOL_PCT) than the base, and
in each scene variant a median absolute error within the sweep's limit of the base's. TPE models feasible and
infeasible proposals apart (Optuna's trial constraints) and the choice takes the feasible candidates with a gain
first (:func:`choice.top_candidates`). Only a candidate that beats the base and every candidate the guide passed
in the generations before is read (one that does not can win nothing the choice would take first), and a reading
stops as soon as the candidate fails a rule (:meth:`SearchGuide.read_all`): a whole read costs about 7 x a fitness on
8 frames.

The guide leads the search, it judges nothing: its scenes are drawn from other seeds than the safety sweep's, and
the sweep still checks every candidate about to win and the chosen one.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from uav_depth.core.errors import UavDepthError
from uav_depth.core.params import StereoParams

from uav_depth.tuning.executor import Executor
from uav_depth.tuning.objective import Evaluation, Task
from uav_depth.tuning.safety import (SweepFrames, errors_both_read, farther_count, median_fails, median_limit_pct,
                                     read_farther, variant_medians, variant_of)

#: What a candidate's evaluation holds of its guide reading (its metrics): the guide frames it read farther than
#: the truth, how many more than the base (the first rule's constraint) and by how many points its worst scene
#: variant's median absolute error exceeds the limit the base sets (the second rule's; 0 when no frame was read by
#: both). The constraints are feasible at 0 or less.
FARTHER, FARTHER_OVER, MEDIAN_OVER = "guide_farther", "guide_farther_over", "guide_median_over"
#: The constraints' names as Optuna records them on each trial, by metric.
CONSTRAINTS = {FARTHER_OVER: "farther", MEDIAN_OVER: "median"}


class SearchGuide:
    """The guide's frames (a :class:`~uav_depth.tuning.safety.SweepFrames` whose frame sets the executor holds)
    and the sweep's rules on them: :meth:`read_base` once, then :meth:`read_all` of candidates;
    :meth:`constraints` and :meth:`feasible` of a stored evaluation."""

    def __init__(self, frames: SweepFrames):
        self.frames = frames
        self.variants = frames.variants
        self._chunks = frames.chunks()
        self._base: tuple[float, ...] | None = None
        self.base_farther: int | None = None

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def ident(self) -> str:
        """What names the guide in cache keys and in a resumed study: its cache entry (rig, scenes, renderer)."""
        return Path(self.frames.path).name

    def framesets(self) -> dict[str, Any]:
        """The executor's frame sets of the guide, one per chunk, a scene variant after the other."""
        return self.frames.framesets()

    def tasks(self, params: Mapping[str, Any]) -> list[Task]:
        """The tasks that read ``params`` on every guide frame, in chunk order."""
        return [self.frames.task(params, j) for j in range(len(self._chunks))]

    def _distances(self, readings: Sequence[Evaluation]) -> tuple[float, ...] | str:
        """Per guide frame, the distance read (m, NaN: none), from :meth:`tasks`' evaluations; or why not."""
        out = [math.nan] * len(self.frames)
        for idx, reading in zip(self._chunks, readings):
            if not reading.ok:
                return f"the search guide: {reading.reason}"
            for i, d in zip(idx, reading.per_frame):
                out[i] = d
        return tuple(out)

    def read_base(self, executor: Executor, base: StereoParams, stop: threading.Event | None = None,
                  tick: Callable[[], None] = lambda: None) -> None:
        """Render the guide (or find it in the caller's cache) and read the base on it, once. ``tick()``: after
        each chunk read."""
        if self._base is not None:
            return
        self.frames.truths          # rendered here, before any worker reads a frame
        got = {}
        for j, ev in executor.imap(self.tasks(base.to_dict()), stop):
            got[j] = ev
            tick()
        if len(got) < len(self._chunks):
            return                  # stopped: the study raises its own interruption next
        distances = self._distances([got[j] for j in range(len(self._chunks))])
        if isinstance(distances, str):
            raise UavDepthError(f"the base parameters cannot be read on the search guide: {distances}")
        self._base, self.base_farther = distances, farther_count(distances, self.frames.truths)

    def read_all(self, executor: Executor, candidates: Sequence[Mapping[str, Any]],
                 stop: threading.Event | None = None,
                 tick: Callable[[], None] = lambda: None) -> list[dict[str, float] | str | None]:
        """The guide metrics of each candidate (after :meth:`read_base`); or why it could not be read (the
        safety sweep would refuse it for the same reason); None for one not judged when ``stop`` was set.
        ``tick()``: after each chunk read.

        A candidate's chunks are judged in order, a scene variant after the other (safety.READ_ORDER), and its
        reading stops at the first chunk after which it fails a rule: more frames read farther than the base (its
        farther constraint is then 1), or a variant read to its end with a median error above the limit (its
        median constraint is that excess). The candidates are read at once (:meth:`Executor.stream`), each
        free worker taking the next chunk of the candidate with the fewest chunks in flight, so that a worker
        reads ahead of a candidate's verdict only when fewer candidates than workers are left. Each verdict
        depends on its own chunks in order alone: 1 or N workers give the same search."""
        assert self._base is not None and self.base_farther is not None, "read_base first"
        reads = [_Reading(self) for _ in candidates]

        def feed() -> tuple[tuple[int, int], Task] | None:
            open_ = [c for c, r in enumerate(reads) if r.verdict is None and r.issued < len(self._chunks)]
            if not open_:
                return None
            c = min(open_, key=lambda c: reads[c].in_flight)
            j = reads[c].issued
            reads[c].issued += 1
            reads[c].in_flight += 1
            return (c, j), self.frames.task(candidates[c], j)

        for (c, j), ev in executor.stream(feed, stop):
            reads[c].in_flight -= 1
            reads[c].take(j, ev)
            tick()
        return [r.verdict for r in reads]

    def _judge_prefix(self, cursor: int, farther: int, distances: Sequence[float]) -> dict[str, float] | None:
        """The metrics once chunks 0..cursor are read: a failed rule, or everything after the last chunk; else
        None (read on)."""
        if farther > self.base_farther:
            return {FARTHER_OVER: 1.0}
        last = cursor == len(self._chunks) - 1
        variant = variant_of(self.frames.keys[self._chunks[cursor][0]])
        if not last and variant_of(self.frames.keys[self._chunks[cursor + 1][0]]) == variant:
            return None
        medians = variant_medians(errors_both_read(self.frames.keys, self.frames.truths, self._base, distances))
        if median_fails(medians.get(variant)):
            _, vb, vt = medians[variant]
            return {MEDIAN_OVER: vt - median_limit_pct(vb)}
        if not last:
            return None
        over = max((vt - median_limit_pct(vb) for _, vb, vt in medians.values()), default=0.0)
        return {FARTHER: farther, FARTHER_OVER: farther - self.base_farther, MEDIAN_OVER: over}

    @staticmethod
    def constraints(ev: Evaluation) -> dict[str, float]:
        """The constraints of a candidate read on the guide, by Optuna's name (a rule not judged, on a candidate
        stopped early, counts as met: it fails the other); none for one not read."""
        if not any(key in ev.metrics for key in CONSTRAINTS):
            return {}
        return {name: float(ev.metrics.get(key, 0.0)) for key, name in CONSTRAINTS.items()}

    @staticmethod
    def feasible(ev: Evaluation) -> bool:
        """Read on the whole guide, and it passes both rules there."""
        return ev.ok and FARTHER in ev.metrics and all(ev.metrics[key] <= 0 for key in CONSTRAINTS)


class _Reading:
    """One candidate's reading on the guide while :meth:`SearchGuide.read_all` runs: its chunks as they come,
    judged in order, and its verdict once it has one (metrics, or why it could not be read)."""

    def __init__(self, guide: SearchGuide):
        self.guide = guide
        self.issued = self.in_flight = 0
        self.verdict: dict[str, float] | str | None = None
        self._got: dict[int, Evaluation] = {}
        self._cursor = self._farther = 0
        self._distances = [math.nan] * len(guide.frames)

    def take(self, j: int, ev: Evaluation) -> None:
        """Chunk ``j``'s evaluation: judged with every chunk before it once they are all here."""
        if self.verdict is not None:
            return                  # read ahead of a verdict: not needed
        if not ev.ok:
            self.verdict = f"the search guide: {ev.reason}"
            return
        g = self.guide
        self._got[j] = ev
        while self.verdict is None and self._cursor in self._got:
            for i, d in zip(g._chunks[self._cursor], self._got.pop(self._cursor).per_frame):
                self._distances[i] = d
                self._farther += read_farther(d, g.frames.truths[i])
            self.verdict = g._judge_prefix(self._cursor, self._farther, self._distances)
            self._cursor += 1
