"""The gate: whether the chosen parameters may replace their base, judged on test frames nothing in the choice
saw, and the :class:`Decision` a tune returns.

The chosen parameters may replace the base only when, on the test frames (:mod:`.split`),

- they score better than the base (the fitness of the run);
- they read no more frames farther than the branch truth by more than 2 % than the base does, and their mean
  safety-weighted branch-distance error is no larger than the base's (a better map must not buy a worse
  distance, the one number the daemon sends; :func:`~uav_depth.tuning.robust.farther_check`);
- on the safety sweep (synthetic frames at the log's rig from inside the minimum range out to 3 m) they read no
  more frames farther than the truth than the base, and no scene variant less accurately (:mod:`.safety`): a
  log holds few frames near the minimum range or with twigs in front, where a tuned matcher goes wrong unseen;
- with ``max_ms``, some evaluated candidate runs within the frame-time budget (else :attr:`Decision.blocked`).

Without test frames (``--test none``, or a log too small to spare any) the gate judges on the frames the choice
was made on, and the report says that figure is not independent of the choice.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from uav_depth.core.params import StereoParams

from uav_depth.tuning.choice import Selection
from uav_depth.tuning.objective import FITNESS, default_convention
from uav_depth.tuning.report import comparison
from uav_depth.tuning.robust import CrossSelection, FartherCheck
from uav_depth.tuning.split import Split
from uav_depth.tuning.study import Study, StudyResult, result_summary


@dataclass(frozen=True)
class Verdict:
    """The gate on the chosen parameters: ``on`` the frames judged ("test", or "validation" / "train" without
    test frames), the base's and the chosen's fitness there, whether it beats the base, the farther check on
    those frames, the safety sweep's (None: none ran, or the base is kept) and the one-line refusal (None: it
    may replace the base)."""

    on: str
    frames: int
    base_value: float
    tuned_value: float
    beats: bool
    farther: FartherCheck
    safety: FartherCheck | None
    refused: str | None


def refusal(metric: str, selection: Selection, verdict_on: str, frames: int, base_value: float,
            tuned_value: float, beats: bool, checks: list[FartherCheck | None], screened: int) -> str | None:
    """The gate's one line, or None when the chosen parameters may replace the base. ``screened``: candidates
    the safety sweep set aside during the choice (said when nothing else beat the base)."""
    reasons = []
    if not selection.beats_base:
        if screened:
            reasons.append(f"{screened} candidate(s) that beat the base on the {selection.on} frames failed the "
                           "safety sweep (report: table.md)")
        best = _best_other(selection)
        reasons.append(f"no candidate beats the base on the {selection.on} frames the choice was made on "
                       + (f"({metric} best {best:.4g} vs base {selection.base[selection.on]:.4g})"
                          if best == best else "(every candidate was set aside: report, table.md)"))
    elif not beats:
        reasons.append(f"the tuned parameters do not beat the base on the {frames} {verdict_on} frame(s) ({metric} "
                       f"{tuned_value:.4g} vs base {base_value:.4g})")
    # reading farther than the branch is refused like a worse score
    reasons += [c.reason for c in checks if c is not None and c.reason]
    return "; ".join(reasons) if reasons else None


def _best_other(selection: Selection) -> float:
    """The choice's value of its best candidate other than the base that may win (NaN: none)."""
    key = f"{selection.on}_utility"
    rows = [r for r in selection.rows[1:] if not r.get("fragile")]
    best = max(rows, key=lambda r: r[key], default=None)
    return float("nan") if best is None else best[selection.on]


@dataclass
class Decision:
    """The outcome of :func:`~uav_depth.tuning.tune.tune`. ``chosen``: the parameters (the base when nothing beat
    it on the validation frames); ``refused``: why they may not replace the base (one line; None when they may);
    ``blocked``: why nothing can be written at all (``max_ms`` met by no candidate), else None.
    ``scores[(i, set)]``: full evaluations of the base (i = 0) and the chosen (i = 1) on ``names``;
    ``frame_ms``: (base, chosen) ms per frame as the daemon flies them, timed side by side (None when the base
    is kept)."""

    request: Any
    split: Split
    framesets: dict[str, Any]
    names: list[str]
    studies: list[Study]
    results: list[StudyResult]
    selection: Selection
    selections: list[Selection]
    cross: CrossSelection | None
    chosen: StereoParams
    scores: dict
    verdict: Verdict
    budget: dict[str, Any] | None
    front: list[dict[str, Any]]
    blocked: str | None
    executor_kind: str
    workers: int
    points: list[tuple[float, float]] = field(default_factory=list)
    frame_ms: tuple[float, float] | None = None
    #: Per fold, what the search guide found (tune._guide_counts); None when the search had no guide.
    guide: list[dict[str, Any]] | None = None

    @property
    def k(self) -> int:
        return self.split.k

    @property
    def study(self) -> Study:
        return self.studies[0]

    @property
    def result(self) -> StudyResult:
        return self.results[0]

    @property
    def refused(self) -> str | None:
        return None if self.blocked else self.verdict.refused

    @property
    def metric(self) -> str:
        return self.request.config.metric

    @property
    def convention(self) -> str:
        return default_convention(self.metric)

    @property
    def chosen_value(self) -> float:
        """The chosen parameters' training fitness."""
        return self.selection.chosen["train"]

    @property
    def counts(self) -> dict[str, int]:
        """Candidates of every fold's search: answered (the progress bar's count: evaluated + from the cache)."""
        evaluated = sum(r.evaluated for r in self.results)
        cached = sum(r.cached for r in self.results)
        return {"candidates": evaluated + cached, "evaluated": evaluated, "cached": cached}

    def summary(self) -> dict[str, Any]:
        """summary.json's content of the decision (the CLI adds where the base and the frames came from)."""
        sel, cross, v = self.selection, self.cross, self.verdict
        cmp = comparison({n: self.scores[(0, n)] for n in self.names}, {n: self.scores[(1, n)] for n in self.names})
        out = result_summary(self.result)
        out.update(counts=self.counts, comparison=cmp, convention=self.convention,
                   budget=self.budget or {"max_ms": None, "front": self.front},
                   chosen={"value": self.chosen_value, "validation_value": sel.chosen["validation"],
                           "test_value": v.tuned_value if v.on == "test" else None, "params": self.chosen.to_dict(),
                           "frame_ms": None if self.frame_ms is None else self.frame_ms[1]},
                   selection={"on": sel.on, "winner": sel.winner, "beats_base": sel.beats_base,
                              "candidates": sel.rows, "folds": _folds_summary(self.selections, self.split)},
                   gate={"on": v.on, "frames": v.frames, "base": v.base_value, "tuned": v.tuned_value,
                         "beats_base": v.beats, "farther": _farther_doc(v.farther),
                         "safety_sweep": None if v.safety is None else _farther_doc(v.safety),
                         "refused": self.refused, "blocked": self.blocked},
                   frames=self.split.roles(), notes=list(self.split.notes), guide=self.guide,
                   frame_ms=None if self.frame_ms is None else {"base": self.frame_ms[0], "tuned": self.frame_ms[1]},
                   references={n: self.framesets[n].reference_sources() for n in self.names},
                   evaluations_per_s=self.result.evaluated / self.result.wall_s if self.result.wall_s > 0 else None)
        if cross is not None:
            out["selection"]["cross_validated"] = {
                "base": cross.cv_base, "tuned": cross.cv_tuned,
                "note": "each fold's winner on the validation sessions it was chosen on: optimistic, not held out "
                        "from the choice (the gate judges on the test frames)"}
        return out


def _farther_doc(check: FartherCheck) -> dict[str, Any]:
    doc = {"base": check.base, "tuned": check.tuned, "frames": check.frames, "refused": check.reason,
           "base_branch_safe": check.base_safe, "tuned_branch_safe": check.tuned_safe}
    if check.base_median is not None:
        doc.update(base_median_abs_error=check.base_median, tuned_median_abs_error=check.tuned_median)
    return doc


def _folds_summary(selections: list[Selection], split: Split) -> list[dict]:
    """Per fold: its frames, and the base's and its winner's train and validation values."""
    out = []
    for j, (sel, (tr, va)) in enumerate(zip(selections, split.folds)):
        out.append({"fold": j + 1, "train_frames": tr.keys, "validation_frames": va.keys,
                    "base_train": sel.base["train"], "base_validation": sel.base["validation"],
                    "winner_train": sel.chosen["train"], "winner_validation": sel.chosen["validation"],
                    "beats_base": sel.beats_base,
                    "rejected": [r["fragile"] for r in sel.rows if r.get("fragile")]})
    return out


def utility(metric: str, value: float) -> float:
    return FITNESS[metric].utility(value)
