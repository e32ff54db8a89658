"""Generalisation checks of the choice: k-fold validation sessions and the perturbation (fragility) check.

**Folds.** With few sessions, one validation split leaves the choice to one or two
scenes. ``--folds`` (auto: :func:`auto_folds`) splits the sessions left after the test split
(:mod:`.split`) into k folds (fold j holds out sessions j, j+k, j+2k ... in name order); each fold runs its
own search on the other sessions and chooses its winner on its own validation sessions (``choice.select``:
those frames were never trained on). The winner of the whole run is the fold winner with the largest gain over
the base on its own validation sessions, among those that beat the base there (:func:`cross_select`; a
winner's score on another fold's validation sessions is not clean: it trained on them). The cross-validated
figure (the mean over folds of each fold's winner on its own validation sessions) is not held out from the
choice: each number in it is the best of the candidates its fold compared on those very frames, so it is
optimistic, and it is reported as such. The gate judges on the test frames (:mod:`.gate`).

**Fragility.** Before a candidate may win, :func:`nudge_check` scores it on the
training frames with each key nudged one step either way (P1, P2 and the speckle
window x0.9 / x1.1, block size +-2 with P1/P2 kept per block pixel, uniqueness +-1, speckle range and
disp12MaxDiff +-1): when one nudge loses the whole gain the candidate had over the
base (or fails), the candidate sits on a cliff and the next one is tried. A key the candidate shares with the
base is nudged in both, and the candidate must still beat the base nudged the same way.

**Farther readings.** :func:`farther_check` is the gate's safety half: a candidate
that reads MORE test frames farther than the branch truth by more than
``metrics.FARTHER_TOL_PCT`` (2 %) than its base does is refused like a worse score,
whatever its mean (a better mean bought with farther readings is the unsafe trade).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import StereoParams, params_from_dict

from uav_depth.tuning.executor import Executor, run_all
from uav_depth.tuning.metrics import FARTHER_TOL_PCT
from uav_depth.tuning.objective import FITNESS, Evaluation, Task
from uav_depth.tuning.report import change_pct

#: auto: k-fold over sessions when a log has at least 2 and at most this many sessions (else one split).
FEW_SESSIONS = 8
#: Folds auto uses (at most one per session).
AUTO_FOLDS = 3
#: Relative step of the multiplicative nudges, and the additive ones (key -> step).
NUDGE_FACTOR = 0.1
NUDGE_STEPS: Mapping[str, int] = {"sgbm.block_size": 2, "sgbm.uniqueness_ratio": 1, "sgbm.speckle_range": 1,
                                  "sgbm.disp12_max_diff": 1}
NUDGE_SCALED: tuple[str, ...] = ("sgbm.p1", "sgbm.p2", "sgbm.speckle_window_size")
#: The block size's nudge keeps P1 and P2 per block pixel: SGBM adds them to matching costs summed over the
#: block, so they scale with its area (OpenCV's sample: P1 = 8 x channels x block_size^2, P2 = 32 x ...). With
#: the same P1/P2, block 1 -> 3 cuts the smoothing ninefold: not one step but a different matcher (measured: at
#: the default 30 x 100 budget on the real pairs every block-1 candidate failed that nudge, and nothing was written).
BLOCK_KEY = "sgbm.block_size"


def parse_folds(text: str | None, n_sessions: int, holdout: str | None) -> int:
    """``--folds``: an integer >= 1, or auto (None): :func:`auto_folds` with ``--holdout auto``, else 1."""
    if text is None or text == "auto":
        return auto_folds(n_sessions) if holdout == "auto" else 1
    try:
        k = int(text)
    except ValueError:
        k = 0
    if k < 1:
        raise ConfigError("--folds", "must be auto or an integer of at least 1", text)
    if k > 1 and holdout != "auto":
        raise ConfigError("--folds", "needs --holdout auto (folds are made of sessions)", text)
    if k > 1 and k > n_sessions:
        raise ConfigError("--folds", f"must not exceed the number of sessions ({n_sessions})", text)
    return k


def auto_folds(n_sessions: int) -> int:
    """k-fold where sessions are few (2..FEW_SESSIONS: min(3, n) folds); one split otherwise."""
    return min(AUTO_FOLDS, n_sessions) if 2 <= n_sessions <= FEW_SESSIONS else 1


def fold_of(index: int, k: int) -> int:
    """The fold that holds out the session at ``index`` (name order)."""
    return index % k


def nudges(params: StereoParams, keys: Sequence[str]) -> list[tuple[str, StereoParams]]:
    """(label, params) for each valid one-step nudge of ``keys`` (those of NUDGE_STEPS / NUDGE_SCALED)."""
    out = []
    for key in keys:
        value = params.get(key)
        if not isinstance(value, int) or isinstance(value, bool):
            continue
        if key in NUDGE_SCALED:
            step = max(1, round(abs(value) * NUDGE_FACTOR))
        elif key in NUDGE_STEPS:
            step = NUDGE_STEPS[key]
        else:
            continue
        for sign in (-1, +1):
            new = value + sign * step
            change = {key: new}
            if key == BLOCK_KEY and new > 0:
                change.update(_penalties_per_area(params, new))
            try:
                nudged = params.replace(**change)
            except ConfigError:
                continue              # off the schema (p1 >= p2, block size 1 - 2 ...): no such neighbour
            out.append((f"{key}{'+' if sign > 0 else '-'}{step}", nudged))
    return out


def _penalties_per_area(params: StereoParams, block: int) -> dict[str, int]:
    """P1 and P2 of ``params`` rescaled from its block size to ``block`` (same penalty per block pixel)."""
    ratio = (block / params.sgbm.block_size) ** 2
    p1 = max(1, round(params.sgbm.p1 * ratio))
    return {"sgbm.p1": p1, "sgbm.p2": max(p1 + 1, round(params.sgbm.p2 * ratio))}


@dataclass(frozen=True)
class NudgeResult:
    """The worst one-step neighbour of a candidate on the training frames."""

    reason: str | None          # why it is fragile, or None
    worst: str | None           # the label of the worst nudge
    worst_value: float
    values: dict[str, float]    # every nudge's training value


def nudge_check(executor: Executor, fitness_name: str, params: StereoParams, value: float, base_value: float,
                keys: Sequence[str], train_set: str = "train", base: StereoParams | None = None,
                base_nudges: dict[str, float] | None = None) -> NudgeResult:
    """Score ``params`` nudged on ``train_set``; fragile when a nudge fails or loses the whole gain over the base.

    ``value`` and ``base_value``: the candidate's and the base's training fitness. With ``base``, a key the
    candidate shares with it is where the base sits too, so that nudge must beat the base nudged the same way
    (the gain must survive the same step), not the base itself: a base at the best block size also scores worse
    at the next one, and that is no cliff of the candidate's (measured: on the noisy rig of bench/new_rig.py every
    candidate of a 30 x 20 tune that kept the base's block size 3 lost its gain at block 5, as did the base).
    ``base_nudges``: the base's nudged values by label, filled here and kept by the caller across candidates.
    """
    fitness = FITNESS[fitness_name]
    cands = nudges(params, keys)
    if not cands:
        return NudgeResult(None, None, math.nan, {})
    labels = {label for label, _ in cands}
    shared = {} if base is None else {
        label: p for label, p in nudges(base, [k for k in keys if base.get(k) == params.get(k)])
        if label in labels}
    memo = {} if base_nudges is None else base_nudges
    todo = [(label, p) for label, p in shared.items() if label not in memo]
    evs = run_all(executor, [Task(p.to_dict(), train_set) for _, p in cands + todo])
    values = {label: (ev.value if ev.ok else fitness.worst) for (label, _), ev in zip(cands, evs)}
    memo.update({label: (ev.value if ev.ok else fitness.worst) for (label, _), ev in zip(todo, evs[len(cands):])})
    bars = {label: (memo[label] if label in shared else base_value) for label in values}

    def shortfall(label: str) -> float:
        return fitness.utility(bars[label]) - fitness.utility(values[label])    # > 0: the nudge lost the gain

    worst = max(values, key=shortfall)
    wv = values[worst]
    reason = None
    if not math.isfinite(wv) or shortfall(worst) > 0:
        than = ("the base with the same nudge" if worst in shared else "the base") + f"'s {bars[worst]:.4g}"
        reason = (f"fragile: {worst} on the training frames scores {fitness_name} {wv:.4g}, worse than {than} "
                  f"(the candidate: {value:.4g}): its gain sits on a cliff")
    return NudgeResult(reason, worst, wv, values)


@dataclass(frozen=True)
class CrossSelection:
    """The winner over k folds. ``folds``: per fold, the base's and the fold winner's train and validation values
    (``choice.Selection`` rows); ``pool``: each distinct fold winner that beat the base on its own validation
    sessions, with its validation value on every fold, their mean (report only) and ``own_gain``
    (:func:`own_gain` on its own fold's);
    ``winner``: index into pool of the largest ``own_gain``, or None (no fold found a non-fragile candidate better
    than its base)."""

    folds: list[dict[str, Any]]
    pool: list[dict[str, Any]]
    winner: int | None
    base_validation: list[float]

    @property
    def cv_base(self) -> float:
        return float(sum(self.base_validation) / len(self.base_validation))

    @property
    def cv_tuned(self) -> float:
        """Mean over folds of each fold's own winner on its own validation sessions. Not held out from the
        choice: each fold's number is the best its choice found on those frames (optimistic; the gate judges on
        the test frames)."""
        return float(sum(f["chosen"]["validation"] for f in self.folds) / len(self.folds))


def cross_select(executor: Executor, fitness_name: str, base: StereoParams, selections: Sequence[Any],
                 validation_sets: Sequence[str]) -> CrossSelection:
    """Among the fold winners (``study.Selection`` of each fold), the one with the largest gain over the base on its
    own fold's validation sessions, the only sessions it did not train on (relative, so that folds of different
    difficulty compare). Each winner is also scored on the other folds' validation sessions, for the report: those
    were in its training set, so their mean favours the winner that fitted its training sessions best (on
    the real pairs at the default 30 x 100 it chose a candidate 3 % better on 11 other scenes over one 15 %
    better; docs/tuning.md). The gate judges on the test frames."""
    fitness = FITNESS[fitness_name]
    folds = [{"base": s.base, "chosen": s.chosen, "beats_base": s.beats_base, "winner": s.winner} for s in selections]
    base_h = [s.base["validation"] for s in selections]
    pool: list[dict[str, Any]] = []
    for j, s in enumerate(selections):
        if not s.beats_base:
            continue                  # it lost to the base on its own validation sessions: it may not win elsewhere
        params = s.chosen["params"]
        if any(p["params"] == params for p in pool):
            continue
        pool.append({"params": params, "fold": j, "validation": [math.nan] * len(selections)})
    tasks, index = [], []
    for i, p in enumerate(pool):
        for j, name in enumerate(validation_sets):
            if j == p["fold"]:
                p["validation"][j] = selections[j].chosen["validation"]
            else:
                tasks.append(Task(p["params"], name))
                index.append((i, j))
    for (i, j), ev in zip(index, run_all(executor, tasks)):
        pool[i]["validation"][j] = ev.value if ev.ok else fitness.worst
    for p in pool:
        p["mean"] = float(sum(p["validation"]) / len(p["validation"]))
        p["own_gain"] = own_gain(fitness, selections[p["fold"]].chosen["validation"], base_h[p["fold"]])
        params_from_dict(p["params"])        # a pooled winner is a valid parameter set
    winner = max(range(len(pool)), key=lambda i: (pool[i]["own_gain"], -i)) if pool else None
    return CrossSelection(folds, pool, winner, base_h)


def own_gain(fitness, value: float, base_value: float) -> float:
    """How much better ``value`` is than ``base_value`` on the same frames, as a share of the base's (> 0: better;
    -inf when the report's :func:`~uav_depth.tuning.report.change_pct` is undefined)."""
    change = change_pct(base_value, value)
    return -math.inf if math.isnan(change) else fitness.direction * change / 100.0


@dataclass(frozen=True)
class FartherCheck:
    """What the daemon would fly, base against candidate, on the same ``frames`` frames with branch truth:
    ``base``/``tuned``, the frames read farther than the truth by more than FARTHER_TOL_PCT;
    ``base_safe``/``tuned_safe``, the mean safety-weighted branch-distance error (%, metrics.safe_branch_error;
    None without such frames). ``base_median``/``tuned_median`` (the safety sweep's only): the median absolute
    branch-distance error (%) over the frames both read. ``reason``: the gate's one line when refused, else None."""

    base: int
    tuned: int
    frames: int
    reason: str | None
    base_safe: float | None = None
    tuned_safe: float | None = None
    base_median: float | None = None
    tuned_median: float | None = None


def count_farther(evaluations: Sequence[Evaluation]) -> tuple[int, int]:
    """(frames read farther than the truth by > FARTHER_TOL_PCT, frames with branch truth) over full evaluations
    (``Evaluation.frame_metrics``' ``farther`` flag, objective._frame_metrics); a failed evaluation counts none."""
    flags = [f["farther"] for ev in evaluations for f in ev.frame_metrics if "farther" in f]
    return int(sum(flag > 0 for flag in flags)), len(flags)


def mean_safe_branch(evaluations: Sequence[Evaluation]) -> float | None:
    """Mean safety-weighted branch-distance error (%) over the frames with branch truth, None without any."""
    values = [f["branch_safe"] for ev in evaluations for f in ev.frame_metrics if "branch_safe" in f]
    return float(sum(values) / len(values)) if values else None


def farther_check(base: Sequence[Evaluation], tuned: Sequence[Evaluation], where: str = "test") -> FartherCheck:
    """The gate's safety rules on what flies: refuse a candidate that reads more frames farther than the truth
    than its base, or whose safety-weighted branch-distance error is larger than the base's.

    ``base`` and ``tuned``: full evaluations of the two on the same frame sets (the frames the choice was made
    on). Equal counts and equal errors pass (the score then decides); frames without branch truth do not count.
    The error rule matters where the fitness mixes the map with the branch (``flown``): a better map must not
    buy a worse distance, the one number the daemon sends.
    """
    nb, frames = count_farther(base)
    nt, frames_t = count_farther(tuned)
    sb, st = mean_safe_branch(base), mean_safe_branch(tuned)
    reason = None
    if frames_t != frames:      # the candidate failed on some: it cannot be shown to read no farther
        reason = (f"the tuned parameters were ranged on {frames_t} of the {frames} {where} frame(s) with branch "
                  "truth")
    elif nt > nb:
        reason = (f"the tuned parameters read {nt} of {frames} {where} frame(s) farther than the branch truth by "
                  f"more than {FARTHER_TOL_PCT:g} %, the base {nb}")
    elif sb is not None and st is not None and st > sb:
        reason = (f"the tuned parameters' safety-weighted branch-distance error on the {frames} {where} frame(s) "
                  f"with branch truth is {st:.4g} %, the base's {sb:.4g} %")
    return FartherCheck(nb, nt, frames, reason, sb, st)
