"""The choice after the search: among the best training candidates, on frames the search did not see.

:func:`select` scores the base and the best training candidates on the validation frames and picks the best one
that may win (not fragile, not refused by a screen); :func:`full_scores` scores parameter sets with every metric
for the report and the gate. Which frames each step may see is the caller's (:mod:`.tune`): the choice never
sees the test frames the gate judges on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from uav_depth.core.params import OPENCV_COST_MAX, StereoParams, params_from_dict

from uav_depth.tuning.executor import Executor, run_all
from uav_depth.tuning.objective import FITNESS, OK, Evaluation, Task
from uav_depth.tuning.robust import nudge_check
from uav_depth.tuning.space import WINNABLE_COST_MAX
from uav_depth.tuning.store import RunStore


def full_scores(executor: Executor, params: Sequence[StereoParams], framesets: Sequence[str],
                convention: str | None = None) -> dict:
    """Every metric (in ``convention``) of each params on each named frame set: {(i, set): Evaluation}."""
    tasks, index = [], []
    for i, p in enumerate(params):
        for name in framesets:
            tasks.append(Task(p.to_dict(), name, full=True, convention=convention))
            index.append((i, name))
    return dict(zip(index, run_all(executor, tasks)))


#: How many of the best training candidates the choice is among (:func:`select`): the best SELECT_TOP
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
    """The winner chosen on the validation frames among the best training candidates.

    ``rows``: one per candidate scored (the base first): params dict, train value,
    validation value (NaN without validation frames), fragile reason. ``winner``: index
    into rows of the best candidate other than the base that is not fragile (0 when
    there is none); ``on``: "validation" or "train" (the frames the choice was made on).
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


def top_candidates(store: RunStore, fitness_name: str, n: int = SELECT_TOP, base_value: float | None = None,
                   feasible: Callable[[Evaluation], bool] | None = None) -> list[tuple[dict[str, Any], float]]:
    """The ``n`` best distinct (params, train value) of every stored evaluation, best first. With ``feasible``
    (the search guide's, :mod:`.guide`) and the base's training value, the candidates that beat the base and
    are feasible come first, each group best first: of the candidates with a gain, they are the ones the safety
    sweep is likely to pass."""
    fitness = FITNESS[fitness_name]

    def led(ev: Evaluation) -> bool:
        return feasible is None or (fitness.utility(ev.value) > fitness.utility(base_value) and feasible(ev))

    rows = [(not led(ev), -fitness.utility(ev.value), i, params, ev.value)
            for i, (_, params, ev) in enumerate(store.evaluations()) if ev.status == OK and not params.get("invalid")]
    rows.sort(key=lambda r: r[:3])
    return [(params, value) for *_, params, value in rows[:n]]


def select(executor: Executor, fitness_name: str, base: StereoParams, base_train: float,
           candidates: Sequence[tuple[dict[str, Any], float]], have_validation: bool, *,
           train_set: str = "train", validation_set: str = "validation",
           nudge_keys: Sequence[str] | None = None,
           screen: Callable[[dict[str, Any]], str | None] | None = None,
           top: int = SELECT_TOP) -> Selection:
    """Score the base and the best ``top`` of ``candidates`` (best training value first) on the validation frames;
    the best one that is not set aside wins.

    Set aside: fragile, i.e. P1/P2 near the cost limit (:func:`fragile_reason`), or, with ``nudge_keys``, a
    one-step nudge of one of those keys on the training frames loses the candidate's whole gain over the base
    (over the base nudged the same way, for a key the two share: ``robust.nudge_check``; checked only for a
    candidate about to win, then the next is tried). ``screen``:
    another check of a candidate about to win that beats the base, returning why it may not (the tuner's
    safety sweep, ``safety.SafetyScreen.reject``) or None; a rejected one is set aside the same way.
    Each candidate set aside is replaced by the next one of ``candidates`` (scored on the validation frames too),
    so the choice is always among ``top`` candidates that may win: a screen that refuses the best ones does not
    narrow it to the rest of a fixed list, and the validation frames never choose among more than ``top``.
    Without validation frames the choice falls back to the training value (reports say so).
    Ties keep the earlier row (the base first, then the better training value).
    """
    fitness = FITNESS[fitness_name]
    rows = [{"params": base.to_dict(), "train": base_train}]
    reserve = [(params, value) for params, value in candidates if params != rows[0]["params"]]
    on = "validation" if have_validation else "train"

    def score(new: list[dict[str, Any]]) -> None:
        held = (run_all(executor, [Task(r["params"], validation_set) for r in new]) if have_validation
                else [None] * len(new))
        for r, ev in zip(new, held):
            r["validation"] = math.nan if ev is None else (ev.value if ev.ok else fitness.worst)
            r["fragile"] = fragile_reason(params_from_dict(r["params"]))
            r["train_utility"] = fitness.utility(r["train"])
            r["validation_utility"] = fitness.utility(r["validation"])

    def fill() -> None:
        """Score more candidates until ``top`` of them may win, or none is left."""
        while reserve and (need := top - sum(r["fragile"] is None for r in rows[1:])) > 0:
            new = [{"params": params, "train": value} for params, value in reserve[:need]]
            del reserve[:need]
            score(new)
            rows.extend(new)

    score(rows)
    fill()
    base_nudges: dict[str, float] = {}      # the base nudged, by label: scored once for every candidate
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
                                nudge_keys, train_set, base, base_nudges)
            r["nudges"] = check.values
            r["fragile"] = check.reason
        if r["fragile"] is None and screen is not None and beats:
            r["fragile"] = screen(r["params"])
        if r["fragile"] is None:
            winner = i
            break
        fill()
    return Selection(rows, winner, on)
