"""The safety weighting: a branch read farther than the truth costs more than one read as much nearer, in the
flown fitness and in the gate that decides whether --out is written."""

import json
import math
import subprocess
import sys
from dataclasses import replace

import pytest

from uav_depth.core.params import load_params, read_provenance, save_params
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.tuning import metrics
from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.split import load_split
from uav_depth.tuning.objective import FITNESS, OK, Evaluation, evaluate
from uav_depth.tuning.robust import farther_check

from .conftest import TINY, TINY_BASE


def test_a_farther_reading_beyond_2pct_costs_more_than_a_miss_and_a_nearer_one_its_error():
    truth = 1.0
    assert metrics.safe_branch_error(0.97, truth) == pytest.approx(3.0)          # nearer: the plain error
    assert metrics.safe_branch_error(1.015, truth) == pytest.approx(1.5)         # farther within 2 %: plain
    assert metrics.safe_branch_error(1.03, truth) == pytest.approx(103.0)        # farther by 3 %: miss + 3
    assert metrics.safe_branch_error(1.03, truth) > metrics.safe_branch_error(None, truth) == 100.0
    assert metrics.safe_branch_error(1.10, truth) > metrics.safe_branch_error(1.03, truth)   # less far, less bad
    # the plain error stays symmetric, for the reports that print it
    assert metrics.branch_error(1.03, truth) == pytest.approx(metrics.branch_error(0.97, truth)) == pytest.approx(3.0)
    assert metrics.is_farther(1.03, truth) and not metrics.is_farther(0.5, truth) and not metrics.is_farther(None, truth)
    assert math.isnan(metrics.branch_signed(None, truth)) and metrics.branch_signed(1.03, truth) == pytest.approx(3.0)


def _with_truth(frames: FrameSet, truths) -> FrameSet:
    return FrameSet(frames.name, tuple(replace(f, branch_distance_m=t) for f, t in zip(frames.frames, truths)))


@pytest.mark.parametrize("metric", ["flown", "branch"])
def test_the_flown_fitness_charges_a_farther_reading_more_than_an_equally_nearer_one(tiny_frames, metric):
    """The same matcher output against two truths: read 3 % farther than one, 3 % nearer than the other."""
    measured = evaluate(TINY_BASE, tiny_frames, FITNESS[metric], full=True)
    got = [f["branch_m"] for f in measured.frame_metrics]
    assert all(math.isfinite(d) for d in got), got        # the base ranges both tiny branches
    farther = evaluate(TINY_BASE, _with_truth(tiny_frames, [d / 1.03 for d in got]), FITNESS[metric], full=True)
    nearer = evaluate(TINY_BASE, _with_truth(tiny_frames, [d / 0.97 for d in got]), FITNESS[metric], full=True)
    # the plain error is about the same (3 % of the truth either way) ...
    assert [f["branch"] for f in farther.frame_metrics] == pytest.approx([3.0, 3.0], abs=0.1)
    assert [f["branch"] for f in nearer.frame_metrics] == pytest.approx([3.0, 3.0], abs=0.1)
    assert [f["farther"] for f in farther.frame_metrics] == [1.0, 1.0]
    assert [f["farther"] for f in nearer.frame_metrics] == [0.0, 0.0]
    # ... the fitness is not: farther by more than 2 % costs a miss on top (100 % x the weight per frame)
    weight = 1.0 if metric == "branch" else 0.1
    assert farther.value - nearer.value == pytest.approx(weight * 100.0, rel=0.01)


def _ev(*flags):
    return Evaluation(OK, 0.0, frame_metrics=tuple({"farther": float(f)} for f in flags))


def test_farther_check_refuses_more_farther_frames_than_the_base_and_passes_as_many():
    same = farther_check([_ev(1, 0, 0)], [_ev(0, 0, 1)])
    assert (same.base, same.tuned, same.frames, same.reason) == (1, 1, 3, None)
    worse = farther_check([_ev(0, 0), _ev(1)], [_ev(1, 0), _ev(1)])
    assert (worse.base, worse.tuned, worse.frames) == (1, 2, 3)
    assert worse.reason == ("the tuned parameters read 2 of 3 test frame(s) farther than the branch truth by "
                            "more than 2 %, the base 1")
    # frames without branch truth do not count; a candidate that failed there cannot pass
    assert farther_check([Evaluation(OK, 0.0, frame_metrics=({"mae": 1.0},))], [_ev()]).reason is None
    assert "ranged on 0 of the 1" in farther_check([_ev(0)], [Evaluation("failed", math.inf)]).reason


def _evs(*pairs):
    """One evaluation of frames given as (farther flag, safety-weighted branch error %)."""
    return Evaluation(OK, 0.0, frame_metrics=tuple({"farther": float(f), "branch_safe": float(e)} for f, e in pairs))


def test_farther_check_refuses_a_larger_branch_error_at_the_same_farther_count():
    """A better map (the flown fitness's larger part) must not buy a worse distance: as many farther frames as
    the base, but a miss where the base read within 1 %, is refused; an equal or smaller error passes."""
    base = [_evs((0, 1.0), (0, 2.0))]
    worse = farther_check(base, [_evs((0, 100.0), (0, 2.0))])
    assert (worse.base, worse.tuned, worse.base_safe, worse.tuned_safe) == (0, 0, 1.5, 51.0)
    assert worse.reason == ("the tuned parameters' safety-weighted branch-distance error on the 2 test frame(s) "
                            "with branch truth is 51 %, the base's 1.5 %")
    assert farther_check(base, [_evs((0, 0.5), (0, 2.5))]).reason is None          # 1.5 against 1.5: equal passes
    assert farther_check(base, [_evs((0, 0.5), (0, 1.0))]).tuned_safe == 0.75
    # the farther count is still the first reason given
    assert "farther than the branch truth" in farther_check(base, [_evs((1, 103.0), (0, 2.0))]).reason


def cli(*args):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=600)


def _set_truth(session, key, truth_m):
    meta = session / "frames" / f"{key.split('/')[1]}_meta.json"
    doc = json.loads(meta.read_text())
    doc["branch_distance_m"] = truth_m
    meta.write_text(json.dumps(doc))


def test_tune_refuses_a_candidate_that_reads_more_test_frames_farther_than_its_base(tmp_path):
    """A real tune twice on the same frames and seed. The paper's mse fitness never looks at the branch truth, so
    both runs choose the same candidate (on the training frames: no validation frame); between them the truth of
    a test frame the candidate ranges (where the base does not, or reads it more than 3 % nearer) is moved
    5 % nearer than the candidate's reading, the other's to the farther of the two readings. The second run must name the farther count in its one-line
    refusal, keep the candidate beside --out, and --force must still write it."""
    root = tmp_path / "log"
    write_session(root / "s", 4, 5, SceneConfig(**TINY), fixed_distance=0.7)   # branches the tiny frames range
    save_params(TINY_BASE, tmp_path / "base.yaml")
    out = tmp_path / "p.yaml"
    args = ["tune", root / "s", "--base", tmp_path / "base.yaml", "--optimizer", "ga", "--metric", "mse",
            "--population", "8", "--generations", "4", "--seed", "7", "--test", "s/000002,s/000003",
            "--holdout", "none",
            "--workers", "1", "--no-progress", "--out", out, "--safety-sweep", "none"]   # the held-out rule alone
    first = cli(*args, "--store", tmp_path / "a.sqlite")
    assert "farther" not in first.stderr, first.stderr     # the truths as rendered: no farther reading
    candidate = tmp_path / ("p.yaml" if first.returncode == 0 else "p.rejected.yaml")
    chosen = load_params(candidate)
    _, held = load_split(root / "s", "s/000002,s/000003", FITNESS["mse"].needs)
    base_m = [f["branch_m"] for f in evaluate(TINY_BASE, held, FITNESS["mse"], full=True,
                                              convention="bench").frame_metrics]
    tuned_m = [f["branch_m"] for f in evaluate(chosen, held, FITNESS["mse"], full=True,
                                               convention="bench").frame_metrics]
    # a test branch the candidate ranges and the base does not, or reads more than 3 % farther than the base
    pick = [i for i, (b, t) in enumerate(zip(base_m, tuned_m)) if math.isfinite(t) and not b * 1.03 >= t]
    assert pick, (base_m, tuned_m)
    for i, frame in enumerate(held.frames):     # the picked one 5 % nearer than the candidate read it; the
        readings = [d for d in (base_m[i], tuned_m[i]) if math.isfinite(d)]    # others where neither is farther
        _set_truth(root / "s", frame.key, tuned_m[i] / 1.05 if i == pick[0] else max(readings, default=1.0))
    for f in (out, candidate):
        f.unlink(missing_ok=True)
    second = cli(*args, "--store", tmp_path / "b.sqlite")
    assert second.returncode == 1, second.stdout
    assert second.stderr.strip().count("\n") == 0
    assert (f"the tuned parameters read 1 of {len(held)} test frame(s) farther than the branch truth by more "
            "than 2 %, the base 0; the candidate is in") in second.stderr
    assert not out.exists() and load_params(tmp_path / "p.rejected.yaml") == chosen
    forced = cli(*args, "--store", tmp_path / "c.sqlite", "--force")
    assert forced.returncode == 0 and "--force" in forced.stdout and read_provenance(out)["forced"] is True
    assert load_params(out) == chosen
