"""The choice's generalisation checks: k-fold by session and the perturbation (fragility) check."""

import json
import subprocess
import sys

import optuna
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.tuning.objective import OK, Evaluation
from uav_depth.tuning.robust import auto_folds, cross_select, nudges, parse_folds
from uav_depth.tuning.store import fold_study_name, storage_url
from uav_depth.tuning.choice import select

from .conftest import TINY, TINY_BASE


class Scripted:
    """An executor whose fitness is a function of (frame set name, parameters): the choice's logic alone."""

    workers, kind = 1, "scripted"

    def __init__(self, fn):
        self.fn, self.calls = fn, []

    def imap(self, tasks, stop=None):
        for i, t in enumerate(tasks):
            self.calls.append((t.frameset, t.params["sgbm"]["p2"]))
            yield i, Evaluation(OK, float(self.fn(t.frameset, t.params["sgbm"])))

    def close(self):
        pass


def _with(p1, p2):
    return DEFAULT_PARAMS.replace(**{"sgbm.p1": p1, "sgbm.p2": p2}).to_dict()


def test_a_candidate_on_a_cliff_loses_to_the_next_one():
    # MAE-like fitness (smaller is better): base 2.0 everywhere. Candidate A (p2 5000) is best held out, but its
    # p2 nudged +10 % (5500) collapses to 9.0 on the training frames. Candidate B (p2 3000) is smooth around it.
    def fn(frameset, sg):
        if sg["p2"] == 2400:
            return 2.0
        if sg["p2"] in (5000,):
            return 1.0 if frameset == "validation" else 1.2
        if sg["p2"] == 5500:
            return 9.0
        return 1.5 if sg["p2"] >= 2700 and sg["p2"] <= 3300 else 1.9
    ex = Scripted(fn)
    cands = [(_with(600, 5000), 1.2), (_with(600, 3000), 1.5)]
    plain = select(ex, "flown", DEFAULT_PARAMS, 2.0, cands, True)
    assert plain.chosen["params"]["sgbm"]["p2"] == 5000          # without the check the cliff wins
    sel = select(ex, "flown", DEFAULT_PARAMS, 2.0, cands, True, nudge_keys=("sgbm.p1", "sgbm.p2"))
    assert sel.chosen["params"]["sgbm"]["p2"] == 3000
    rejected = sel.rows[1]
    assert "fragile: sgbm.p2+500" in rejected["fragile"] and rejected["nudges"]["sgbm.p2+500"] == 9.0
    assert ("train", 5500) in ex.calls and ("validation", 5500) not in ex.calls   # nudges on the training frames


@pytest.mark.parametrize("nudged_candidate, fragile", [(4.0, False), (6.0, True)], ids=["keeps-its-gain", "loses-it"])
def test_a_key_the_candidate_shares_with_the_base_is_judged_against_the_base_nudged_the_same_way(nudged_candidate,
                                                                                                 fragile):
    """Candidate: the base's block size, P2 3000 (train 1.5 against the base's 2.0). At the next block size
    both score worse (the base 5.0): the candidate is fragile only when it scores worse than the base nudged the
    same way, not merely worse than the base."""
    block = DEFAULT_PARAMS.sgbm.block_size

    def fn(frameset, sg):
        if sg["block_size"] != block:              # P1 and P2 scaled per block pixel: the candidate's stay higher
            return nudged_candidate if sg["p2"] > 2400 * (sg["block_size"] / block) ** 2 * 1.1 else 5.0
        return {2400: 2.0, 3000: 1.5}.get(sg["p2"], 1.8)
    ex = Scripted(fn)
    sel = select(ex, "flown", DEFAULT_PARAMS, 2.0, [(_with(600, 3000), 1.5)], True,
                 nudge_keys=("sgbm.p2", "sgbm.block_size"))
    row = sel.rows[1]
    assert (sel.winner == 0) is fragile
    if fragile:
        assert row["fragile"].startswith(f"fragile: sgbm.block_size") and "the base with the same nudge's 5" in row[
            "fragile"]
    else:
        assert row["fragile"] is None and row["nudges"][f"sgbm.block_size+2"] == 4.0


def test_a_screened_candidate_is_set_aside_for_the_next_one_that_beats_the_base():
    """The tuner's safety sweep screens the held-out choice: the best held-out candidate (p2 5000) is refused by
    the screen, the runner-up (p2 3000) wins; a candidate that does not beat the base is never screened."""
    def fn(frameset, sg):
        return {2400: 2.0, 5000: 1.0, 3000: 1.5, 2600: 2.5}[sg["p2"]]
    asked = []

    def screen(params):
        asked.append(params["sgbm"]["p2"])
        return "unsafe: reads 1 of the 84 safety-sweep frame(s) farther" if params["sgbm"]["p2"] == 5000 else None
    cands = [(_with(600, 5000), 1.0), (_with(600, 3000), 1.5), (_with(600, 2600), 2.5)]
    sel = select(Scripted(fn), "flown", DEFAULT_PARAMS, 2.0, cands, True, screen=screen)
    assert sel.chosen["params"]["sgbm"]["p2"] == 3000 and sel.beats_base
    assert sel.rows[1]["fragile"].startswith("unsafe: reads 1 of the 84")
    assert asked == [5000, 3000]
    # every candidate that beats the base refused: the best of the rest wins, which does not beat the base
    sel = select(Scripted(fn), "flown", DEFAULT_PARAMS, 2.0, cands, True, screen=lambda params: "unsafe")
    assert sel.chosen["params"]["sgbm"]["p2"] == 2600 and not sel.beats_base


def test_each_candidate_set_aside_is_replaced_by_the_next_best_in_training():
    """The choice is among ``top`` candidates that may win: the screen refuses the two best held out, so the
    third in training order (held back until then) is scored on the held-out frames and wins; the fourth is
    never scored. A candidate above the cost limit counts as set aside from the start."""
    def fn(frameset, sg):
        return {2400: 2.0, 5000: 1.0, 4000: 1.1, 3000: 1.5, 2600: 1.8, 2200: 1.9}[sg["p2"]]
    refused = {5000, 4000}
    cands = [(_with(600, 5000), 1.0), (_with(600, 4000), 1.1), (_with(600, 3000), 1.5), (_with(600, 2600), 1.8)]
    ex = Scripted(fn)
    sel = select(ex, "flown", DEFAULT_PARAMS, 2.0, cands, True, top=2,
                 screen=lambda params: "unsafe: farther" if params["sgbm"]["p2"] in refused else None)
    assert sel.chosen["params"]["sgbm"]["p2"] == 3000 and sel.beats_base
    assert [r["params"]["sgbm"]["p2"] for r in sel.rows] == [2400, 5000, 4000, 3000, 2600]
    assert ("validation", 2600) in ex.calls       # replaced the second refusal, ranked below 3000
    # Without replacements (a list of two) every candidate that beats the base is refused: the base stays.
    sel = select(Scripted(fn), "flown", DEFAULT_PARAMS, 2.0, cands[:2], True, top=2,
                 screen=lambda params: "unsafe: farther" if params["sgbm"]["p2"] in refused else None)
    assert sel.winner == 0
    # A fragile candidate (P2 above the winnable bound) is replaced before anything is screened.
    cliff = DEFAULT_PARAMS.replace(**{"sgbm.p1": 600, "sgbm.p2": 20000}).to_dict()
    ex = Scripted(lambda frameset, sg: {20000: 0.5}.get(sg["p2"]) or fn(frameset, sg))
    sel = select(ex, "flown", DEFAULT_PARAMS, 2.0, [(cliff, 0.5)] + cands[2:], True, top=1)
    assert sel.chosen["params"]["sgbm"]["p2"] == 3000
    assert ("validation", 2600) not in ex.calls


def test_nudges_step_each_key_and_stay_on_the_schema():
    p = DEFAULT_PARAMS.replace(**{"sgbm.block_size": 3, "sgbm.p1": 100, "sgbm.p2": 101})
    labels = dict(nudges(p, ("sgbm.p1", "sgbm.p2", "sgbm.block_size", "sgbm.uniqueness_ratio", "wls.lambda")))
    assert set(labels) == {"sgbm.p1-10", "sgbm.p2+10", "sgbm.block_size-2", "sgbm.block_size+2",
                           "sgbm.uniqueness_ratio-1", "sgbm.uniqueness_ratio+1"}   # p1+10 >= p2, p2-10 <= p1
    assert labels["sgbm.block_size-2"].sgbm.block_size == 1


def test_the_block_size_nudge_keeps_p1_and_p2_per_block_pixel():
    """SGBM adds P1/P2 to costs summed over the block, so a block-size neighbour scales them with its area
    (OpenCV's sample: 8 and 32 x channels x block_size^2). Unscaled, block 1 -> 3 with P1 20 / P2 30 smooths a
    ninth as much: every block-1 candidate of the default 30 x 100 tune on real pairs failed that nudge."""
    p = DEFAULT_PARAMS.replace(**{"sgbm.block_size": 1, "sgbm.p1": 20, "sgbm.p2": 30})
    labels = dict(nudges(p, ("sgbm.block_size",)))
    assert set(labels) == {"sgbm.block_size+2"}                     # block -1 is off the schema
    up = labels["sgbm.block_size+2"].sgbm
    assert (up.block_size, up.p1, up.p2) == (3, 180, 270)
    p = DEFAULT_PARAMS.replace(**{"sgbm.block_size": 5, "sgbm.p1": 600, "sgbm.p2": 601})
    down = dict(nudges(p, ("sgbm.block_size",)))["sgbm.block_size-2"].sgbm
    assert (down.block_size, down.p1, down.p2) == (3, 216, 217)     # 600 x 9 / 25; P2 stays above P1
    # The other keys' nudges leave P1/P2 alone.
    assert dict(nudges(p, ("sgbm.uniqueness_ratio",)))["sgbm.uniqueness_ratio+1"].sgbm.p1 == 600


def test_cross_select_takes_the_fold_winner_with_the_largest_gain_on_its_own_validation_sessions():
    # p2 3000 won fold 0 narrowly (1.9 against the base's 2.0) and scores superbly on folds 1-2, which it trained
    # on; p2 4000 won fold 1 by 40 % (1.2). The mean over the folds would take 3000 (0.97 against 1.37): it
    # rewards fitting the training sessions. Only a winner's own fold is clean: 4000 wins.
    table = {2400: (2.0, 2.0, 2.0), 3000: (1.9, 0.5, 0.5), 4000: (1.5, 1.2, 1.4), 5000: (0.1, 0.1, 2.5)}
    ex = Scripted(lambda fs, sg: table[sg["p2"]][{"validation": 0, "validation1": 1, "validation2": 2, "validation3": 2}.get(fs, 0)])

    class Sel:
        def __init__(self, p2, fold):
            self.base = {"params": DEFAULT_PARAMS.to_dict(), "train": 2.0, "validation": 2.0}
            self.chosen = {"params": _with(600, p2), "train": 1.0, "validation": table[p2][min(fold, 2)]}
            self.winner, self.beats_base = 1, True
    lost = Sel(5000, 3)
    lost.beats_base = False        # it lost on its own fold: never pooled, whatever it scores elsewhere
    cross = cross_select(ex, "flown", DEFAULT_PARAMS, [Sel(3000, 0), Sel(4000, 1), Sel(4000, 2), lost],
                         ["validation", "validation1", "validation2", "validation3"])
    assert len(cross.pool) == 2 and cross.pool[cross.winner]["params"]["sgbm"]["p2"] == 4000
    assert cross.pool[0]["validation"] == [1.9, 0.5, 0.5, 0.5]
    assert cross.pool[0]["own_gain"] == pytest.approx(0.05) and cross.pool[1]["own_gain"] == pytest.approx(0.4)
    assert cross.pool[0]["mean"] < cross.pool[1]["mean"]        # the mean, reported, would have taken the other
    assert cross.cv_tuned == pytest.approx((1.9 + 1.2 + 1.4 + 2.5) / 4) and cross.cv_base == 2.0


def test_folds_are_auto_where_sessions_are_few_and_checked():
    assert [auto_folds(n) for n in (1, 2, 3, 6, 8, 9)] == [1, 2, 3, 3, 3, 1]
    assert parse_folds("auto", 6, "auto") == 3 and parse_folds("auto", 6, "0.3") == 1 and parse_folds("1", 6, "auto") == 1
    for text, holdout, match in (("0", "auto", "at least 1"), ("4", "auto", "must not exceed"),
                                 ("2", "none", "needs --holdout auto")):
        with pytest.raises(ConfigError, match=match):
            parse_folds(text, 3, holdout)


@pytest.fixture(scope="module")
def four_sessions(tmp_path_factory):
    from uav_depth.core.params import save_params

    root = tmp_path_factory.mktemp("folds")
    for i, name in enumerate(("a", "b", "c", "d")):
        write_session(root / "log" / name, 2, 11 + i, SceneConfig(**TINY))
    save_params(TINY_BASE, root / "base.yaml")
    return root


def test_tune_k_fold_by_session_searches_each_fold_and_reports_train_vs_validation(four_sessions, tmp_path):
    root = four_sessions
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "tune", root / "log", "--base",
                           root / "base.yaml", "--optimizer", "random", "--population", "4", "--generations", "1",
                           "--workers", "1", "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml",
                           "--no-progress", "--force", "--safety-sweep", "none"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "3-fold validation (chosen on it): " in proc.stdout and "test (2, unseen by the choice)" in proc.stdout
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["frames"]["test"] == ["d/000000", "d/000001"]      # set aside before the folds
    folds = summary["selection"]["folds"]
    assert [f["validation_frames"] for f in folds] == [["a/000000", "a/000001"], ["b/000000", "b/000001"],
                                                       ["c/000000", "c/000001"]]
    for f in folds:
        assert not set(f["train_frames"]) & set(f["validation_frames"]) and len(f["train_frames"]) == 4
        assert not set(f["train_frames"]) & set(summary["frames"]["test"])
        for key in ("base_train", "winner_train", "base_validation", "winner_validation"):
            assert isinstance(f[key], float)
    cands = summary["selection"]["candidates"]
    for row in cands[1:]:
        assert row["validation"] == pytest.approx(sum(row["validation_per_fold"]) / 3)
    assert cands[0]["validation"] == pytest.approx(sum(f["base_validation"] for f in folds) / 3)
    assert summary["gate"]["on"] == "test" and summary["gate"]["frames"] == 2
    studies = {s.study_name: s.n_trials for s in optuna.get_all_study_summaries(storage_url(tmp_path / "rep" /
                                                                                            "store.sqlite"))}
    assert set(studies) == {fold_study_name(j) for j in range(3)} and all(n >= 2 for n in studies.values())
    table = (tmp_path / "rep" / "table.md").read_text()
    assert "3-fold by session" in table and "Gate, on the 2 test frame(s)" in table
