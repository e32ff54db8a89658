"""Studies: deterministic whatever the workers, cached, failures recorded, fitness variants."""

import math

import numpy as np
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.tuning.executor import ProcessExecutor, SerialExecutor, make_executor, run_all
from uav_depth.tuning.frames import FrameData, FrameSet
from uav_depth.tuning.objective import FITNESS, Task, evaluate
from uav_depth.tuning.store import RunStore
from uav_depth.tuning.front import pareto_front
from uav_depth.tuning.study import Study, StudyConfig, candidate_key

from .conftest import TINY_BASE


def _run(frames, workers, tmp_path=None, **cfg):
    config = StudyConfig(**{"population": 6, "generations": 3, "seed": 11, **cfg})
    store = RunStore(tmp_path / "s.sqlite" if tmp_path else ":memory:")
    with (SerialExecutor({"train": frames}, config.metric) if workers == 1
          else ProcessExecutor({"train": frames}, config.metric, workers)) as ex:
        study = Study(config, frames, ex, store, TINY_BASE)
        return study.run(), store


def _signature(result):
    return [(r.best_key, repr(r.best_value), repr(r.history)) for r in result.runs]


@pytest.mark.parametrize("optimizer", ["ga-paper", "ga"])
def test_same_seed_same_result_with_one_and_two_workers(tiny_frames, optimizer):
    one, store1 = _run(tiny_frames, 1, optimizer=optimizer, runs=2)
    two, store2 = _run(tiny_frames, 2, optimizer=optimizer, runs=2)
    assert _signature(one) == _signature(two)
    trials = store1.trials()
    assert trials == store2.trials()          # every proposal and its fitness, bit for bit
    assert len(trials) == 2 * 6 * 3
    by_run = [[t[3] for t in trials if t[0] == r] for r in (0, 1)]
    assert by_run[0] != by_run[1]             # the runs' seeds differ


def test_different_seeds_differ(tiny_frames):
    a, _ = _run(tiny_frames, 1, optimizer="ga", seed=1)
    b, _ = _run(tiny_frames, 1, optimizer="ga", seed=2)
    assert _signature(a) != _signature(b)


def test_identical_candidates_are_evaluated_once(tiny_frames):
    result, store = _run(tiny_frames, 1, optimizer="ga-paper", population=8, generations=4)
    proposals = sum(r.proposals for r in result.runs) + 1   # + the baseline
    assert result.evaluated + result.cached == proposals
    assert result.cached >= 5 * 3          # at least the five elites of every later generation
    rows = list(store.evaluations())
    assert len({k for k, _, _ in rows}) == len(rows)
    assert len([r for r in rows if not r[1].get("invalid")]) == result.evaluated


def test_best_so_far_never_worsens_and_beats_or_equals_the_base(tiny_frames):
    result, _ = _run(tiny_frames, 1, optimizer="ga", generations=4)
    h = result.runs[0].history
    assert all(b <= a for a, b in zip(h, h[1:]))
    assert h[-1] <= result.baseline.value    # the improved GA starts from the base (mse: lower is better)


def test_the_papers_ga_spends_no_trial_on_a_value_the_schema_refuses(tiny_frames):
    """The paper's ranges put most genomes above OpenCV's 16-bit cost limit; decoded into what the daemon
    accepts (paper_space), none of them is a failed trial for a reason the schema could have known."""
    result, store = _run(tiny_frames, 1, optimizer="ga-paper", population=10, generations=3)
    reasons = [ev.reason for _, _, ev in store.evaluations() if ev.status == "failed"]
    assert not any("must be" in r or "16-bit" in r for r in reasons), reasons
    assert len(result.runs[0].history) == 3 and result.runs[0].proposals == 30


class _RefusedSpace:
    """A space whose every genome stands for a value the schema refuses (a seam for the failed-trial path)."""

    name, size = "refused", 1

    def decode(self, genome, base=None):
        return {"wls.sigma_color": 0.0}


def test_a_candidate_the_schema_rejects_is_a_failed_trial(tiny_frames):
    config = StudyConfig(optimizer="ga-paper", population=2, generations=1)
    with SerialExecutor({"train": tiny_frames}, "mse") as ex:
        study = Study(config, tiny_frames, ex, RunStore(), DEFAULT_PARAMS)
        study.space = _RefusedSpace()
        key, params, ev = study.candidate([0.5])
        assert ev.status == "failed" and "wls.sigma_color must be greater than 0" in ev.reason
        assert ev.value == math.inf                          # the worst mse
        assert study.evaluate([(key, params, ev)])[0] is ev
        assert study.store.get(key).reason == ev.reason


def test_a_candidate_that_raises_is_a_failed_trial(tiny_frames):
    bad = FrameSet("train", (FrameData("odd/0", tiny_frames.frames[0].left, tiny_frames.frames[0].right[:, :-8],
                                       tiny_frames.frames[0].reference),))
    ev = evaluate(TINY_BASE, bad, FITNESS["mse"])
    assert ev.status == "failed" and "FrameError" in ev.reason and ev.value == math.inf


@pytest.mark.parametrize("metric", ["mse", "psnr", "ssim", "bad2", "branch"])
def test_every_fitness_scores_the_baseline(tiny_frames, metric):
    ev = evaluate(TINY_BASE, tiny_frames, FITNESS[metric])
    assert ev.status == "ok" and len(ev.per_frame) == 2 and math.isfinite(ev.value)
    assert ev.value == pytest.approx(np.mean(ev.per_frame))
    full = evaluate(TINY_BASE, tiny_frames, FITNESS[metric], full=True, convention="paper")
    # the branch fitness is the safety-weighted error; the report keeps the plain one as "branch" beside it
    key = "branch_safe" if metric == "branch" else metric
    assert full.value == ev.value and full.metrics[key] == pytest.approx(ev.value)
    assert {"mse", "psnr", "ssim", "bad2", "valid", "branch"} <= set(full.metrics)
    assert [f["id"] for f in full.frame_metrics] == ["tiny/000000", "tiny/000001"]
    bench = evaluate(TINY_BASE, tiny_frames, FITNESS[metric], full=True, convention="bench")
    assert {"mae", "rmse", "bad1", "bad2", "bad4", "psnr", "density", "branch", "branch_safe", "farther", "truth_m",
            "branch_m"} == set(bench.metrics)


@pytest.mark.parametrize("metric", ["flown", "flown-bad2"])
def test_flown_fitness_scores_what_ranging_consumes_and_ignores_wls_smoothing(tiny_frames, metric):
    ev = evaluate(TINY_BASE, tiny_frames, FITNESS[metric])
    assert ev.status == "ok" and math.isfinite(ev.value) and ev.value > 0
    # lambda and sigma change the WLS map (the paper's fitness) but never what the ranging uses
    smooth = TINY_BASE.replace(**{"wls.lambda": 90000.0, "wls.sigma_color": 5.0})
    assert evaluate(smooth, tiny_frames, FITNESS[metric]).per_frame == ev.per_frame
    assert evaluate(smooth, tiny_frames, FITNESS["mse"]).value != evaluate(TINY_BASE, tiny_frames,
                                                                            FITNESS["mse"]).value
    # the matcher's own parameters do change it
    other = TINY_BASE.replace(**{"sgbm.uniqueness_ratio": 40, "sgbm.p2": 9000})
    assert evaluate(other, tiny_frames, FITNESS[metric]).per_frame != ev.per_frame


def test_flown_fitness_scores_the_map_over_the_matched_region_and_the_branch_in_the_ranging_region(tiny_frames):
    """The map over everything the candidate matches (a ninth of the frame chooses parameters that do not
    generalise, issue 12), the branch where the daemon ranges: a frame's ranging ROI moves the branch term only."""
    import dataclasses

    from uav_depth.core.disparity import flight_pipeline
    from uav_depth.core.ranging import resolve_roi
    from uav_depth.tuning import metrics
    from uav_depth.tuning.objective import BRANCH_PX_PER_PCT, bench, branch_reading, flown_map

    pipeline = flight_pipeline(TINY_BASE)
    for f in tiny_frames.frames:
        res = pipeline.run(f.left, f.right)
        h, w = f.left.shape[:2]
        whole = bench(f, flown_map(res), (0, 0, w, h))["mae"]
        assert abs(whole - bench(f, flown_map(res), resolve_roi(f.roi, w, h))["mae"]) > 0.01  # regions differ
        for roi in (f.roi, (0, 0, w // 4, h // 4)):      # the branch's region, and a corner away from it
            frame = dataclasses.replace(f, roi=roi)
            reading = branch_reading(frame, res, TINY_BASE).distance_m
            branch = BRANCH_PX_PER_PCT * metrics.safe_branch_error(reading, f.branch_distance_m)
            value = evaluate(TINY_BASE, FrameSet("one", (frame,)), FITNESS["flown"]).value
            assert value == pytest.approx(whole + branch, abs=1e-9)
        assert reading is None or abs(reading - f.branch_distance_m) > 0.05   # the corner misses the branch


def test_branch_fitness_is_the_daemons_ranging_error(tiny_frames):
    ev = evaluate(TINY_BASE, tiny_frames, FITNESS["branch"])
    # the baseline ranges tiny synthetic branches within a few %, or reports no measurement (the ranging's
    # quality gate), which costs the full 100 %; a reading more than 2 % farther than the truth costs more
    # (the safety weighting, metrics.safe_branch_error)
    assert min(ev.per_frame) < 10 and all(v < 10 or v >= 100.0 for v in ev.per_frame)
    # a matcher that sees nothing near cannot range the branch: the miss costs 100 %
    blind = TINY_BASE.replace(**{"sgbm.num_disparities": 16, "sgbm.min_disparity": 0})
    assert evaluate(blind, tiny_frames, FITNESS["branch"]).value > ev.value


def test_selfsup_fitness_needs_no_reference(tiny_frames):
    no_ref = FrameSet("train", tuple(FrameData(f.key, f.left, f.right) for f in tiny_frames.frames))
    assert FITNESS["selfsup"].needs == ()
    good = evaluate(TINY_BASE, no_ref, FITNESS["selfsup"], full=True)
    bad = evaluate(TINY_BASE.replace(**{"sgbm.uniqueness_ratio": 95}), no_ref, FITNESS["selfsup"])
    assert good.status == "ok" and 0 <= good.value <= 1
    assert "mse" not in good.metrics
    assert bad.value > good.value


def test_cache_key_depends_on_params_frames_and_metric():
    p = DEFAULT_PARAMS.to_dict()
    k = candidate_key(p, "f1", "mse")
    assert k == candidate_key(DEFAULT_PARAMS.to_dict(), "f1", "mse")
    assert len({k, candidate_key(p, "f2", "mse"), candidate_key(p, "f1", "ssim"),
                candidate_key(DEFAULT_PARAMS.replace(**{"sgbm.p1": 601}).to_dict(), "f1", "mse")}) == 4


def test_process_pool_loads_frames_once_and_keeps_task_order(tiny_frames):
    tasks = [Task(TINY_BASE.replace(**{"sgbm.p1": p1}).to_dict()) for p1 in (100, 300, 600, 900, 1200)]
    with make_executor({"train": tiny_frames}, "mse", 2) as ex:
        pooled = run_all(ex, tasks)
    with make_executor({"train": tiny_frames}, "mse", 1) as ex:
        serial = run_all(ex, tasks)
    assert [e.value for e in pooled] == [e.value for e in serial]
    assert len({e.value for e in serial}) == 5


@pytest.mark.parametrize("workers", [1, 2])
def test_a_stream_keeps_one_task_a_worker_and_asks_what_next_when_one_finishes(tiny_frames, workers):
    """stream starts a task only on a free worker (nothing queued that a caller could no longer take back), asks
    the feed again after each one finishes, and ends when nothing runs and the feed has nothing; after stop, it
    starts nothing more."""
    import threading

    params = [TINY_BASE.replace(**{"sgbm.p1": p1}).to_dict() for p1 in (100, 300, 600, 900, 1200, 1500)]
    todo, in_flight, most = list(enumerate(params)), [0], [0]

    def feed():
        if not todo:
            return None
        in_flight[0] += 1
        most[0] = max(most[0], in_flight[0])
        i, p = todo.pop(0)
        return ("p1", i), Task(p)

    got = []
    with make_executor({"train": tiny_frames}, "mse", workers) as ex:
        for handle, ev in ex.stream(feed):
            in_flight[0] -= 1
            got.append((handle, ev.value))
        assert most[0] == workers and sorted(h for h, _ in got) == [("p1", i) for i in range(6)]
        stop, seen = threading.Event(), []
        todo[:] = list(enumerate(params))
        for handle, ev in ex.stream(feed, stop):
            seen.append(handle)
            stop.set()
        assert len(seen) == workers and len(todo) == 6 - workers   # what was running is yielded, nothing more


def test_pareto_front():
    pts = [(1.0, 10.0, "a"), (2.0, 20.0, "b"), (0.5, 30.0, "c"), (3.0, 40.0, "d"), (2.5, 5.0, "e")]
    assert [p[2] for p in pareto_front(pts)] == ["e", "d"]


@pytest.mark.parametrize("kw, match", [
    (dict(population=1), "--population must be an integer of at least 2"),
    (dict(generations=0), "--generations must be an integer of at least 1"),
    (dict(metric="mae"), "--metric must be one of"),
    (dict(optimizer="pso"), "--optimizer must be one of"),
    (dict(seed=-1), "--seed must be a non-negative integer"),
], ids=["population", "generations", "metric", "optimizer", "seed"])
def test_bad_study_config_is_clear(kw, match):
    with pytest.raises(ConfigError, match=match):
        StudyConfig(**kw)


@pytest.mark.parametrize("metric", ["mse", "ssim", "bad2", "selfsup"])
def test_a_candidate_with_a_region_is_scored_inside_it(tiny_frames, metric):
    """The flight parameters compute only compute.roi: the unanswered rest is by design, not an error."""
    from uav_depth.core.disparity import DisparityPipeline
    from uav_depth.tuning import metrics
    from uav_depth.tuning.selfsup import selfsup_loss

    roi = (0.25, 0.25, 0.75, 0.75)
    flight = TINY_BASE.replace(**{"compute.roi": roi})
    ev = evaluate(flight, tiny_frames, FITNESS[metric], full=True)
    per_frame = []
    for f in tiny_frames.frames:
        h, w = f.left.shape[:2]
        x0, y0, x1, y1 = flight.compute.roi_pixels(w, h)
        assert (x0, y0, x1, y1) == (w // 4, h // 4, 3 * w // 4, 3 * h // 4)
        disp = DisparityPipeline(flight).compute(f.left, f.right)
        assert np.isnan(disp[:, :x0]).all()          # outside: unanswered
        if metric == "selfsup":
            per_frame.append(selfsup_loss(f.left, f.right, disp, box=(x0, y0, x1, y1)))
            whole = selfsup_loss(f.left, f.right, disp)
        else:
            fn = {"mse": metrics.mse, "ssim": metrics.ssim, "bad2": lambda r, e: metrics.bad(r, e, 2.0)}[metric]
            per_frame.append(fn(f.reference[y0:y1, x0:x1], disp[y0:y1, x0:x1]))
            whole = fn(f.reference, disp)
        # scored over the whole frame, the empty border would dominate
        assert FITNESS[metric].utility(per_frame[-1]) > FITNESS[metric].utility(whole)
    assert ev.per_frame == pytest.approx(per_frame)
    if metric != "selfsup":
        assert ev.metrics["valid"] > 0.8       # the valid fraction is of the region, too


def test_the_flown_fitness_ranges_with_the_ranging_settings_it_is_given(tiny_frames):
    """The flown fitness scores the pixels the ranging uses and the distance it sends: both follow the ranging
    settings of the config that will fly, and so does the cache key of every evaluation."""
    from uav_depth.core.ranging import RangingConfig
    from uav_depth.tuning.objective import Objective, Task

    strict = RangingConfig(min_confidence=0.95)
    default = Objective({"train": tiny_frames}, "flown")(Task(TINY_BASE.to_dict(), "train", full=True))
    stricter = Objective({"train": tiny_frames}, "flown", strict)(Task(TINY_BASE.to_dict(), "train", full=True))
    assert default.ok and stricter.ok and default.value != stricter.value
    assert default.metrics["density"] > stricter.metrics["density"]           # fewer confident pixels used
    params = TINY_BASE.to_dict()
    assert candidate_key(params, "d", "flown") != candidate_key(params, "d", "flown", strict)
