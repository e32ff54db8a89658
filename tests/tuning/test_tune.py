"""tuning.tune: one tune as a library call (no CLI), which frames each step sees, and a leak that would be caught."""

from __future__ import annotations

import threading

import pytest

from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.tuning import choice
from uav_depth.tuning.choice import Selection
from uav_depth.tuning.gate import refusal
from uav_depth.tuning.robust import FartherCheck
from uav_depth.tuning.study import TuneInterrupted
from uav_depth.tuning.tune import Hooks, LeakError, TuneRequest, study_config, tune

from .conftest import TINY, TINY_BASE


@pytest.fixture(scope="module")
def four_sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("tune")
    for i, name in enumerate(("a", "b", "c", "d")):
        write_session(root / name, 2, 11 + i, SceneConfig(**TINY))
    return root


def _request(logdir, tmp_path, **kw) -> TuneRequest:
    return TuneRequest(str(logdir), study_config("random", None, None, None, 4, 1, 1, 0), TINY_BASE,
                       str(tmp_path / "store.sqlite"), workers=1, **kw)


def test_tune_is_a_library_call_whose_gate_judges_on_frames_the_choice_never_saw(four_sessions, tmp_path):
    phases: list[str] = []
    d = tune(_request(four_sessions, tmp_path), Hooks(phase=phases.append))
    # auto: the last quarter of the sessions is the test (d), the rest 3 folds by session (a, b, c)
    assert d.k == 3 and d.cross is not None and d.metric == "flown"
    roles = d.split.roles()
    assert roles["test"] == ["d/000000", "d/000001"]
    assert sorted(roles["validation"]) == ["a/000000", "a/000001", "b/000000", "b/000001", "c/000000", "c/000001"]
    assert not set(roles["test"]) & (set(roles["train"]) | set(roles["validation"]))
    for (tr, va) in d.split.folds:
        assert not set(tr.keys) & set(va.keys) and len(va) == 2 and len(tr) == 4
    # the gate judged on the test frames, and the report's figures for it are the test frames' own
    assert d.verdict.on == "test" and d.verdict.frames == 2
    assert d.verdict.base_value == d.scores[(0, "test")].value
    summary = d.summary()
    assert summary["gate"]["on"] == "test" and summary["frames"]["test"] == roles["test"]
    assert "optimistic" in summary["selection"]["cross_validated"]["note"]
    assert (d.refused is None) == (d.verdict.beats and d.verdict.farther.reason is None)
    assert any("fold 3 of 3" in p for p in phases) and any("2 test frame(s)" in p for p in phases)


def test_a_choice_that_peeks_at_the_test_frames_is_caught(four_sessions, tmp_path, monkeypatch):
    """A choice that scores its candidates on the test frames would make the gate's figure a chosen one, not a
    held-out one: the tune refuses to go on, it does not pass unnoticed."""
    real = choice.select

    def peeking(executor, *args, validation_set="validation", **kw):
        return real(executor, *args, validation_set="test", **kw)

    monkeypatch.setattr("uav_depth.tuning.tune.select", peeking)
    with pytest.raises(LeakError, match="the choice asked to score candidates on the test frames"):
        tune(_request(four_sessions, tmp_path))


def test_a_single_session_is_split_in_contiguous_blocks_and_the_report_warns(tmp_path):
    log = tmp_path / "log"
    write_session(log / "s", 8, 3, SceneConfig(**TINY))
    d = tune(_request(log / "s", tmp_path, safety=None))
    roles = d.split.roles()
    assert roles["train"] == [f"s/{i:06d}" for i in range(4)]          # the first block trains
    assert roles["validation"] == ["s/000004", "s/000005"]             # the next one chooses
    assert roles["test"] == ["s/000006", "s/000007"]                   # the last one judges
    assert any("same flight" in n and "correlated" in n for n in d.split.notes)
    assert d.summary()["notes"] == list(d.split.notes)


def test_a_set_stop_event_interrupts_the_tune(four_sessions, tmp_path):
    stop = threading.Event()
    stop.set()
    with pytest.raises(TuneInterrupted):
        tune(_request(four_sessions, tmp_path), Hooks(stop=stop))


def test_a_refusal_says_when_the_safety_sweep_set_aside_every_candidate_that_beat_the_base():
    """A tune whose six best validation candidates all beat the base and all failed the sweep keeps the base; the
    one line must say why, not only that nothing beat the base."""
    rows = [{"params": {}, "validation": 20.3, "validation_utility": -20.3},
            {"params": {"x": 1}, "validation": 18.5, "validation_utility": -18.5, "fragile": "unsafe: reads 14 .."}]
    sel = Selection(rows, 0, "validation")
    none = FartherCheck(0, 0, 0, None)
    line = refusal("flown", sel, "test", 2, 20.3, 20.3, False, [none], screened=1)
    assert line == ("1 candidate(s) that beat the base on the validation frames failed the safety sweep (report: "
                    "table.md); no candidate beats the base on the validation frames the choice was made on (every "
                    "candidate was set aside: report, table.md)")
    assert not refusal("flown", sel, "test", 2, 20.3, 20.3, False, [none], 0).startswith("1 candidate")
    # a choice that beat the base on its validation frames but not on the test frames: the test says so
    won = Selection(rows[:1] + [dict(rows[1], fragile=None)], 1, "validation")
    assert refusal("flown", won, "test", 2, 20.3, 20.9, False, [none], 0) == (
        "the tuned parameters do not beat the base on the 2 test frame(s) (flown 20.9 vs base 20.3)")
