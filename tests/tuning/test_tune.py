"""tuning.tune: one tune as a library call (no CLI), and where its farther gate counts."""

from __future__ import annotations

import threading

import pytest

from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.robust import CrossSelection
from uav_depth.tuning.choice import Selection
from uav_depth.tuning.study import TuneInterrupted
from uav_depth.tuning.tune import Hooks, TuneRequest, farther_sets, set_names, study_config, tune

from .conftest import TINY, TINY_BASE, _tiny_frames


def _sets(k: int) -> dict[str, FrameSet]:
    frames = _tiny_frames(2, 7)
    return {n: frames for pair in set_names(k) for n in pair}


def _cross(winner_fold: int | None) -> CrossSelection:
    pool = [] if winner_fold is None else [{"params": DEFAULT_PARAMS.to_dict(), "fold": winner_fold,
                                            "holdout": [1.0, 1.0, 1.0], "mean": 1.0}]
    return CrossSelection([], pool, None if winner_fold is None else 0, [2.0, 2.0, 2.0])


def test_the_farther_gate_counts_only_frames_the_chosen_did_not_train_on():
    sel = Selection([{"params": {}}], 0, "holdout")
    # one split: the frames the choice was made on
    assert farther_sets(1, sel, None, set_names(1), _sets(1)) == (["holdout"], [])
    assert farther_sets(1, Selection([{"params": {}}], 0, "train"), None, set_names(1), _sets(1)) == (["train"], [])
    # 3 folds, the winner from fold 3: it trained on folds 1 and 2's held-out sessions, so only fold 3's count
    own, cv = farther_sets(3, sel, _cross(2), set_names(3), _sets(3))
    assert own == ["holdout2"]
    assert cv == [(0, "holdout"), (1, "holdout1"), (2, "holdout2")]    # each with its own fold's winner
    assert farther_sets(3, sel, _cross(None), set_names(3), _sets(3))[0] == []   # the base is kept


@pytest.fixture(scope="module")
def three_sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("tune")
    for i, name in enumerate(("a", "b", "c")):
        write_session(root / name, 2, 11 + i, SceneConfig(**TINY))
    return root


def test_tune_is_a_library_call_that_returns_the_decision(three_sessions, tmp_path):
    phases: list[str] = []
    request = TuneRequest(str(three_sessions), study_config("random", None, None, None, 4, 1, 1, 0), TINY_BASE,
                          str(tmp_path / "store.sqlite"), workers=1)
    d = tune(request, Hooks(phase=phases.append))
    assert d.k == 3 and d.cross is not None and d.metric == "flown"          # auto: 3 folds for 3 sessions
    assert [len(ho) for _, ho in d.folds] == [2, 2, 2]
    assert d.cv_farther is not None and d.cv_farther.frames == 6              # every session held out once
    # the gate's verdict and its one line agree; this seed's fold winners lose to the base held out
    assert d.beats is False and d.refused.startswith("the tuned parameters do not beat the base on the held-out "
                                                     "sessions of 3 folds")
    assert d.chosen == TINY_BASE and d.farther.frames == 0                     # nothing new to count
    assert any("fold 3 of 3" in p for p in phases)
    assert d.summary()["selection"]["farther"]["cross_validated"]["frames"] == 6


def test_a_set_stop_event_interrupts_the_tune(three_sessions, tmp_path):
    stop = threading.Event()
    stop.set()
    request = TuneRequest(str(three_sessions), study_config("random", None, None, None, 4, 1, 1, 0), TINY_BASE,
                          str(tmp_path / "store.sqlite"), workers=1)
    with pytest.raises(TuneInterrupted):
        tune(request, Hooks(stop=stop))


def test_a_refusal_says_when_the_safety_sweep_set_aside_every_candidate_that_beat_the_base():
    """The near-frames tune of 2026-12-05 resumed with the screen: its six best held-out candidates all beat the base
    and all failed the 330-frame sweep, so the base stayed the choice; the one line must say why, not only that
    nothing beat the base."""
    from uav_depth.tuning.robust import FartherCheck
    from uav_depth.tuning.tune import _refusal

    rows = [{"params": {}, "holdout": 20.3, "holdout_utility": -20.3},
            {"params": {"x": 1}, "holdout": 18.5, "holdout_utility": -18.5, "fragile": "unsafe: reads 14 of ..."}]
    sel = Selection(rows, 0, "holdout")
    holdout = _tiny_frames(2, 0)
    none = FartherCheck(0, 0, 0, None)
    line = _refusal("flown", 1, sel, None, holdout, False, none, None, None, screened=1)
    assert line == ("1 candidate(s) that beat the base on held-out frames failed the safety sweep (report: table.md); "
                    "the tuned parameters do not beat the base on the 2 held-out frame(s) (flown 20.3 vs base 20.3)")
    assert not _refusal("flown", 1, sel, None, holdout, False, none, None, None).startswith("1 candidate")
