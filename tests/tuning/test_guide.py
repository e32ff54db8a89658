"""tuning.guide: the search guide that leads TPE's search to where the safety sweep will pass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import params_from_dict
from uav_depth.core.session import SessionWriter
from uav_depth.sim.sweep import VARIANTS, at_rig, render_with_truth
from uav_depth.tuning.choice import top_candidates
from uav_depth.tuning.executor import SerialExecutor
from uav_depth.tuning.guide import FARTHER, FARTHER_OVER, MEDIAN_OVER, SearchGuide
from uav_depth.tuning.metrics import is_farther
from uav_depth.tuning.objective import OK, Evaluation, branch_distances
from uav_depth.tuning.optimizers import OPTIMIZERS, TPESearch
from uav_depth.tuning.safety import SweepFrames
from uav_depth.tuning.space import SchemaSpace
from uav_depth.tuning.store import RunStore
from uav_depth.tuning.study import Study, StudyConfig, candidate_key

from .conftest import TINY, TINY_BASE

#: Six leafy and six plain branches at the tiny rig: three chunks of the executor's tasks.
DISTANCES = (0.6, 0.8, 1.0, 1.2, 1.4, 1.6)


@pytest.fixture(scope="module")
def guide_frames(tmp_path_factory) -> SweepFrames:
    path = tmp_path_factory.mktemp("guide") / "guide"
    items = [(f"{v}-s20-{d:.2f}m", at_rig(VARIANTS[v](d, 20), TINY["width"], TINY["height"], TINY["focal_px"],
                                          0.06)) for v in ("leafy", "plain") for d in DISTANCES]

    def render():
        truths = []
        for i, (_, cfg) in enumerate(items):
            left, right, truth, roi = render_with_truth(cfg)
            SessionWriter(path, cfg.calibration).write(i, left, right, meta={"branch_distance_m": truth,
                                                                            "roi": list(roi)})
            truths.append(truth)
        return truths
    return SweepFrames(str(path), [f"{i:06d}" for i in range(len(items))], [k for k, _ in items], render, "guide")


#: A poor base (large blocks blur the branch's edges) that about half of a small search's candidates beat.
POOR_BASE = TINY_BASE.replace(**{"sgbm.block_size": 15})


def _study(frames, guide_frames, optimizer, store=None, base=TINY_BASE, **cfg):
    guide = SearchGuide(guide_frames)
    executor = SerialExecutor({"train": frames, **guide.framesets()}, "flown")
    config = StudyConfig(**{"optimizer": optimizer, "population": 6, "generations": 2, "seed": 3, **cfg})
    return Study(config, frames, executor, store or RunStore(":memory:"), base, guide=guide), executor


def _farther_on(params, guide_frames) -> int:
    """The guide frames ``params`` reads farther than the truth, counted afresh as the safety sweep counts."""
    from uav_depth.core.session import iter_frames
    from uav_depth.tuning.frames import FrameSet, load_frame

    fs = FrameSet("g", tuple(load_frame(r) for r in iter_frames(guide_frames.path)))
    return sum(is_farther(None if d is None or not math.isfinite(d) else d, f.branch_distance_m)
               for d, f in zip(branch_distances(params, fs), fs.frames))


def test_a_guided_study_reads_the_candidates_with_a_gain_on_the_guide_as_the_safety_sweep_counts(tiny_frames,
                                                                                                  guide_frames):
    """The base is read once. A candidate that beats the base and every candidate the guide passed before is read
    on it and its metrics stored: a full reading gives the frames read farther (as counted afresh), how many more
    than the base, and its worst scene variant's median error over the sweep rule's limit; a reading stopped at
    the first frame more than the base's reads is 1 over. The others are not read."""
    study, ex = _study(tiny_frames, guide_frames, "tpe", generations=3, base=POOR_BASE, seed=4)
    with ex:
        result = study.run()
    assert study.guide.base_farther == _farther_on(POOR_BASE, guide_frames)
    base = result.baseline.value
    rows = [(params, ev) for _, params, ev in study.store.evaluations() if ev.ok]
    read = [(p, ev) for p, ev in rows if FARTHER_OVER in ev.metrics]
    assert 3 <= len(read) < len(rows) and all(ev.value < base for _, ev in read)
    full = [(p, ev) for p, ev in read if FARTHER in ev.metrics]
    stopped = [(p, ev) for p, ev in read if FARTHER not in ev.metrics]
    assert full and stopped
    assert all(ev.metrics[FARTHER_OVER] == 1.0 and MEDIAN_OVER not in ev.metrics for _, ev in stopped)
    for params, ev in full:
        assert ev.metrics[FARTHER] == _farther_on(params_from_dict(params), guide_frames) <= study.guide.base_farther
        assert ev.metrics[FARTHER_OVER] == ev.metrics[FARTHER] - study.guide.base_farther
        assert math.isfinite(ev.metrics[MEDIAN_OVER])
    for params, ev in stopped:
        assert _farther_on(params_from_dict(params), guide_frames) > study.guide.base_farther
    # a candidate with a gain that was not read is no better than one the guide passed (in a generation before)
    best_passed = min((ev.value for _, ev in read if SearchGuide.feasible(ev)), default=base)
    assert all(ev.value >= best_passed for _, ev in rows if ev.value < base and FARTHER_OVER not in ev.metrics)
    assert study.identity()["guide"] == SearchGuide(guide_frames).ident


def test_the_guides_median_rule_is_the_safety_sweeps(guide_frames):
    """A candidate that reads every plain frame 5 % long and the rest as the base exceeds the limit by 5 - (1.1 x
    the base's median + 0.25) points; one that reads as the base is 0.25 + 0.1 x its median under it. A
    candidate that reads more frames farther than the base is stopped: 1 over the first rule. The plain frames
    are read first, and a candidate whose plain median fails is stopped there."""
    from uav_depth.tuning.metrics import branch_signed
    from uav_depth.tuning.objective import OK, Evaluation
    from uav_depth.tuning.safety import median_limit_pct

    guide = SearchGuide(guide_frames)
    truths = guide_frames.truths
    base = [t * 1.01 for t in truths]                       # 1 % long everywhere
    guide._base, guide.base_farther = tuple(base), 0
    long = [t * 1.05 if k.startswith("plain") else b for k, t, b in zip(guide_frames.keys, truths, base)]

    class Reads:
        """An executor whose candidate reads ``distances`` on the guide, chunk by chunk."""

        def __init__(self, distances):
            self.distances = distances

        def stream(self, feed, stop=None):
            while (item := feed()) is not None:
                j = int(item[1].frameset.removeprefix(guide.frames.prefix))
                yield item[0], Evaluation(OK, math.nan, per_frame=tuple(self.distances[i] for i in guide._chunks[j]))

    mb = abs(branch_signed(base[0], truths[0]))
    [same] = guide.read_all(Reads(base), [TINY_BASE.to_dict()])
    assert same[FARTHER] == 0 and same[MEDIAN_OVER] == pytest.approx(mb - median_limit_pct(mb))
    guide.base_farther = 6        # as if the base read the 6 plain frames farther: the first rule holds ...
    [worse] = guide.read_all(Reads(long), [TINY_BASE.to_dict()])
    excess = float(np.median([abs(branch_signed(d, t)) for k, d, t in zip(guide_frames.keys, long, truths)
                              if k.startswith("plain")])) - median_limit_pct(mb)
    assert excess > 3 and worse == {MEDIAN_OVER: pytest.approx(excess)}      # ... the plain frames, read first, fail
    guide.base_farther = 0        # the base reads none farther: stopped at the first chunk (4 plain frames 5 % long)
    assert guide.read_all(Reads(long), [TINY_BASE.to_dict()]) == [{FARTHER_OVER: 1.0}]
    assert guide.variants == ["plain", "leafy"]


def test_candidates_read_at_once_get_the_verdict_each_gets_alone_on_one_or_two_workers(tiny_frames,
                                                                                       guide_frames):
    """read_all reads several candidates at once, each worker taking the next chunk of the candidate with the
    fewest in flight; each verdict is judged on its own chunks in order, so it is the one the candidate gets read
    alone on one worker, and a candidate stopped early has nothing read past its stop but what was in flight."""
    from uav_depth.tuning.executor import make_executor

    candidates = [TINY_BASE.replace(**kv).to_dict() for kv in (
        {"sgbm.block_size": 7}, {"sgbm.num_disparities": 16}, {"sgbm.block_size": 15}, {"sgbm.p2": 2000},
        {"wls.enabled": False}, {"sgbm.block_size": 3})]
    guide = SearchGuide(guide_frames)
    framesets = {"train": tiny_frames, **guide.framesets()}
    with make_executor(framesets, "flown", 1) as ex:
        guide.read_base(ex, TINY_BASE)
        alone = [guide.read_all(ex, [c])[0] for c in candidates]
    for workers in (1, 2):
        with make_executor(framesets, "flown", workers) as ex:
            counted = Counting(ex)
            assert guide.read_all(counted, candidates) == alone
        stopped = [i for i, v in enumerate(alone) if FARTHER not in v]
        assert stopped and len(counted.read) < len(candidates) * len(guide._chunks)
        assert max(counted.ahead) <= max(1, workers - 1)
    assert [FARTHER in v for v in alone] == [False, True, False, True, False, True]     # three stopped early


class Counting:
    """An executor's stream that counts the chunks read per candidate and, for each one started, how many chunks
    of its candidate were already in flight."""

    def __init__(self, executor):
        self.executor, self.read, self.ahead = executor, [], []

    def stream(self, feed, stop=None):
        in_flight: dict[int, int] = {}

        def counted():
            item = feed()
            if item is not None:
                c = item[0][0]
                self.ahead.append(in_flight.get(c, 0))
                in_flight[c] = in_flight.get(c, 0) + 1
                self.read.append(item[0])
            return item
        for handle, ev in self.executor.stream(counted, stop):
            in_flight[handle[0]] -= 1
            yield handle, ev


def test_only_an_optimiser_that_takes_constraints_reads_the_guide(tiny_frames, guide_frames):
    assert [name for name, spec in OPTIMIZERS.items() if spec.guided] == ["tpe"]
    study, ex = _study(tiny_frames, guide_frames, "ga", generations=1)
    with ex:
        study.run()
    assert study.guide is None and study.identity()["guide"] is None
    assert all(FARTHER not in ev.metrics for _, _, ev in study.store.evaluations())


def test_the_guide_is_part_of_the_cache_key_and_of_what_a_resumed_study_must_share(tiny_frames, guide_frames,
                                                                                  tmp_path):
    params = TINY_BASE.to_dict()
    assert candidate_key(params, "d", "flown") != candidate_key(params, "d", "flown", guide="guide-640x480-x")
    assert candidate_key(params, "d", "flown", guide="a") != candidate_key(params, "d", "flown", guide="b")
    store = tmp_path / "s.sqlite"
    first, ex = _study(tiny_frames, guide_frames, "tpe", RunStore(store), generations=1)
    with ex:
        first.open(False)
        first.run()
    first.store.close()
    unguided = Study(first.config, tiny_frames, ex, RunStore(store), TINY_BASE)
    with pytest.raises(ConfigError, match=r"--resume \(guide\)"):
        unguided.open(True)


def test_tpe_takes_each_proposals_guide_constraints():
    opt = TPESearch(SchemaSpace(), 4, np.random.default_rng(0), TINY_BASE)
    opt.ask()
    opt.tell([1.0, 2.0, -math.inf, 3.0], [{"farther": 0.0, "median": -0.3}, {"farther": 3.0, "median": 0.5}, {},
                                          {}])
    trials = opt.study.trials
    assert [t.constraints for t in trials] == [{"farther": 0.0, "median": -0.3}, {"farther": 3.0, "median": 0.5},
                                               {}, {}]
    assert trials[2].state.name == "FAIL"
    ev = Evaluation(OK, 1.0, {FARTHER: 4, FARTHER_OVER: 0, MEDIAN_OVER: -0.2})
    assert SearchGuide.constraints(ev) == {"farther": 0.0, "median": -0.2} and SearchGuide.feasible(ev)
    assert not SearchGuide.feasible(Evaluation(OK, 1.0, {FARTHER: 5, FARTHER_OVER: 1, MEDIAN_OVER: -0.2}))
    assert not SearchGuide.feasible(Evaluation(OK, 1.0, {FARTHER: 4, FARTHER_OVER: 0, MEDIAN_OVER: 0.1}))
    assert not SearchGuide.feasible(Evaluation(OK, 1.0)) and SearchGuide.constraints(Evaluation(OK, 1.0)) == {}


def _ev(value: float, over: int | None) -> Evaluation:
    return Evaluation(OK, value, {} if over is None else {FARTHER: 5 + over, FARTHER_OVER: over, MEDIAN_OVER: -1.0})


def test_the_choice_takes_the_candidates_that_beat_the_base_and_pass_the_guide_first():
    """Base: flown 10. Best first among those with a gain that pass the guide; one that passes without a gain
    (it measures little, so it reads little farther) does not jump ahead of better ones."""
    store = RunStore(":memory:")
    rows = {"a": (8.0, 4), "b": (9.0, 0), "c": (9.5, -3), "d": (12.0, None), "e": (7.0, 1), "f": (11.0, -5)}
    for i, (name, (value, over)) in enumerate(rows.items()):
        params = TINY_BASE.replace(**{"sgbm.p1": 8 + i}).to_dict()
        params["name"] = name
        store.put(name, params, None, _ev(value, over))
    order = [p["name"] for p, _ in top_candidates(store, "flown", 6, 10.0, SearchGuide.feasible)]
    assert order == ["b", "c", "e", "a", "f", "d"]
    assert [p["name"] for p, _ in top_candidates(store, "flown", 6)] == ["e", "a", "b", "c", "f", "d"]
