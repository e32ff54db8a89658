"""Fitness metrics and the evaluation of one candidate (a *trial*).

Evaluating a candidate = ``DisparityPipeline(params).run`` on every frame, each
result scored by the fitness metric, averaged over the frames. A candidate that
raises, or leaves a frame without a single valid pixel, is a FAILED evaluation
with its reason and the worst fitness; it never stops a run.

:data:`FITNESS` is the registry (name -> :class:`Fitness`); the CLI's
``--metric`` choices are its keys. Two families:

- the *flown* fitnesses (``flown``, ``flown-bad2``) score what the daemon's
  ranging consumes: the matcher's measured pixels where the left-right confidence
  reaches the ranging's ``min_confidence`` (:func:`flown_map`), over everything the
  candidate matches (its ``compute.roi``, else the whole frame), in the benchmark
  convention (``metrics.bench_scores``), plus the branch-distance error of the
  daemon's own ranging stage, in the frame's ranging region, where the frame knows
  the truth. WLS smoothing never reaches them, so its parameters are not searched.
  The map is scored over the matched region, not the ranging region alone: the
  parameters act on the whole frame, and a ninth of it over a few frames is too few
  pixels to choose them by (measured: :func:`_flown`).
- the paper's fitnesses (``mse``, ``psnr``, ``ssim``, ``bad2``) score the WLS map in
  the paper's convention (invalid = 0, per-frame peak): the faithful mode.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np

from uav_depth.core.disparity import DisparityPipeline, DisparityResult, flight_pipeline
from uav_depth.core.errors import ParameterWarning
from uav_depth.core.calibration import Calibration
from uav_depth.core.params import StereoParams, params_from_dict
from uav_depth.core.ranging import Measurement, Ranger, RangingConfig, resolve_roi

from uav_depth.tuning import metrics
from uav_depth.tuning.frames import FrameData, FrameSet

OK, FAILED = "ok", "failed"


@dataclass(frozen=True)
class Fitness:
    """One fitness metric: per-frame score of a pipeline result, ranged (where it ranges) with the
    ``ranging:`` settings of the config that will fly.

    ``direction``: +1 larger is better, -1 smaller is better. ``needs``: what a
    frame must have to be scored ("reference", "branch").
    """

    name: str
    direction: int
    needs: tuple[str, ...]
    score: Callable[[FrameData, DisparityResult, StereoParams, RangingConfig], float]
    doc: str

    @property
    def worst(self) -> float:
        return -math.inf if self.direction > 0 else math.inf

    def utility(self, value: float) -> float:
        """Larger-is-better view used by every optimiser (NaN -> -inf)."""
        return -math.inf if math.isnan(value) else self.direction * value


def scored_box(params: StereoParams, shape: tuple[int, ...]) -> metrics.Box:
    """Where a candidate is scored: its ``compute.roi`` (the whole frame unless it sets one)."""
    return params.compute.roi_pixels(shape[1], shape[0])


#: The ranging settings of a daemon run without a config's ``ranging:`` section (min_confidence 0.5 ...): what
#: the flown fitness ranges with unless the tune is given the config that will fly (``tune --config``).
FLOWN_RANGING = RangingConfig()
#: Weight of the branch-distance error in the flown fitness: 10 % of branch error costs as much as 1 px
#: of mean disparity error (a 1 px error is about 10 % of distance at 10 px of disparity).
BRANCH_PX_PER_PCT = 0.1


def flown_map(res: DisparityResult, min_confidence: float = FLOWN_RANGING.min_confidence) -> np.ndarray:
    """(H, W) float32 px: what the ranging stage uses, NaN elsewhere.

    The measured pixels (``DisparityResult.measured``, no WLS fill-in) whose
    left-right confidence is at least ``min_confidence``, as ``Ranger.measure``
    selects them (it also drops disparities below its distance floor).
    """
    if res.confidence is None:
        return res.measured
    with np.errstate(invalid="ignore"):
        return np.where(res.confidence >= min_confidence, res.measured, np.float32(np.nan)).astype(np.float32)


def bench(frame: FrameData, estimate: np.ndarray, box: metrics.Box) -> dict[str, float]:
    """Benchmark-convention metrics of ``estimate`` against the frame's reference inside ``box``.

    The strip and the PSNR peak come from the frame's ground truth alone (the same for
    every candidate): strip = its largest disparity, peak = that rounded up to a multiple
    of 16 (the search range that covers it).
    """
    strip = metrics.strip_px(frame.reference)
    peak = 16.0 * max(1, math.ceil(strip / 16.0))
    ref, est = metrics.in_box(box, frame.reference, estimate)
    return metrics.bench_scores(ref, est, peak, strip - box[0])


def _flown(metric: str) -> Callable[[FrameData, DisparityResult, StereoParams, RangingConfig], float]:
    """The flown fitness with ``metric`` for the map: scored over the candidate's matched region, the branch in
    the ranging region.

    Why not the map in the ranging region alone (measured on 17 real pairs, tune on 6, report on 11, TPE 160
    proposals, seeds 0-2, ``bench/tune_region.py``): scored there, the search cut the training error in that
    region by 33-37 % and the held-out error in it by only 7-15 %; scored over the matched region, it cut the
    held-out error in the ranging region by 14-22 %. The parameters act on the whole frame; a ninth of it
    over a few frames is too few pixels to choose them by."""
    def score(frame: FrameData, res: DisparityResult, params: StereoParams, ranging: RangingConfig) -> float:
        value = bench(frame, flown_map(res, ranging.min_confidence), scored_box(params, frame.left.shape))[metric]
        if frame.has_branch:   # safety-weighted: farther costs more
            value += BRANCH_PX_PER_PCT * _branch(frame, res, params, ranging)
        return value
    return score


def _ref(fn: Callable[[np.ndarray, np.ndarray], float]
         ) -> Callable[[FrameData, DisparityResult, StereoParams, RangingConfig], float]:
    return lambda frame, res, params, ranging: fn(*metrics.in_box(scored_box(params, frame.reference.shape),
                                                                  frame.reference, res.disparity))


def frame_ranger(frame: FrameData, params: StereoParams, ranging: RangingConfig = FLOWN_RANGING) -> Ranger:
    """The daemon's own ranging stage for ``params`` at ``frame``'s rig, with ``ranging``'s settings, in the
    frame's region (where its truth was measured; the config's ``ranging.roi`` when the frame has none).
    Its limits: ``.limits``."""
    h, w = frame.left.shape[:2]
    cal = Calibration(focal_px=frame.focal_px, baseline_m=frame.baseline_m, width=w, height=h)
    roi = resolve_roi(frame.roi if frame.roi is not None else ranging.roi, w, h)
    return Ranger(replace(ranging, roi=roi), cal, roi, params)


def branch_reading(frame: FrameData, res: DisparityResult, params: StereoParams,
                   ranging: RangingConfig = FLOWN_RANGING) -> Measurement:
    """The daemon's own ranging stage on this result: its whole reading (the distance, or why there is none)."""
    return frame_ranger(frame, params, ranging).measure(res)


def branch_distance(frame: FrameData, res: DisparityResult, params: StereoParams,
                    ranging: RangingConfig = FLOWN_RANGING) -> float | None:
    """The daemon's own ranging stage on this result: the branch distance in m, None when it measured nothing."""
    return branch_reading(frame, res, params, ranging).distance_m


def branch_distances(params: StereoParams, frames: FrameSet,
                     ranging: RangingConfig = FLOWN_RANGING) -> list[float | None]:
    """The daemon's distance on each frame as it flies (core.disparity.flight_pipeline, then its ranging stage),
    None where it measured nothing: unlike :func:`evaluate`, a frame the matcher answers nowhere (a branch filling
    the view) is a frame without a measurement, not a failed candidate. Raises what the pipeline raises."""
    pipeline = flight_pipeline(params)
    out = []
    for frame in frames.frames:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ParameterWarning)
            res = pipeline.run(frame.left, frame.right)
        out.append(None if res.warning is not None else branch_distance(frame, res, params, ranging))
    return out


def branch_measurement(frame: FrameData, res: DisparityResult, params: StereoParams,
                       ranging: RangingConfig = FLOWN_RANGING) -> tuple[float | None, float]:
    """(distance m or None, plain symmetric error % against the frame's truth: metrics.branch_error)."""
    distance = branch_distance(frame, res, params, ranging)
    return distance, metrics.branch_error(distance, frame.branch_distance_m)


def _branch(frame: FrameData, res: DisparityResult, params: StereoParams,
            ranging: RangingConfig = FLOWN_RANGING) -> float:
    """The daemon's own ranging stage on this result, against the frame's truth, safety-weighted
    (metrics.safe_branch_error: a reading farther than the truth by more than 2 % costs more than a miss)."""
    return metrics.safe_branch_error(branch_distance(frame, res, params, ranging), frame.branch_distance_m)


def _selfsup(frame: FrameData, res: DisparityResult, params: StereoParams, ranging: RangingConfig) -> float:
    # Imported on use: the tuner runs without the self-supervised loss's extra dependencies for every other
    # metric.
    from uav_depth.tuning.selfsup import selfsup_loss

    return float(selfsup_loss(frame.left, frame.right, res.disparity, box=scored_box(params, frame.left.shape)))


FITNESS: dict[str, Fitness] = {
    "flown": Fitness("flown", -1, ("reference",), _flown("mae"),
                     "what flies: mean absolute error (px, benchmark convention) of the confident measured pixels "
                     f"over the matched region, + {BRANCH_PX_PER_PCT} x the safety-weighted branch-distance error (%) "
                     "in the ranging region where known (farther than the truth by > 2 % costs more than a miss)"),
    "flown-bad2": Fitness("flown-bad2", -1, ("reference",), _flown("bad2"),
                          "as flown, bad-2 (%) instead of the mean absolute error"),
    "mse": Fitness("mse", -1, ("reference",), _ref(metrics.mse), "mean squared disparity error, px^2"),
    "psnr": Fitness("psnr", +1, ("reference",), _ref(metrics.psnr), "peak signal-to-noise ratio, dB"),
    "ssim": Fitness("ssim", +1, ("reference",), _ref(metrics.ssim), "structural similarity, 0..1"),
    "bad2": Fitness("bad2", -1, ("reference",), _ref(lambda r, e: metrics.bad(r, e, 2.0)),
                    "% of reference pixels off by more than 2 px"),
    "branch": Fitness("branch", -1, ("branch",), _branch,
                      "relative error of the daemon's branch distance (its ranging stage) against the truth, %, "
                      "safety-weighted (metrics.safe_branch_error)"),
    "selfsup": Fitness("selfsup", -1, (), _selfsup, "reference-free loss (uav_depth.tuning.selfsup)"),
}


@dataclass(frozen=True)
class Evaluation:
    """The outcome of one candidate on one frame set.

    ``value``: mean fitness over frames (the fitness's worst when failed).
    ``metrics``: means over frames of every metric the frames allow (full
    evaluations only). ``ms``: mean pipeline time per frame. ``per_frame``: the
    fitness of each frame, in frame order; ``frame_metrics`` every metric of each
    frame (full evaluations only).
    """

    status: str
    value: float
    metrics: Mapping[str, float] = field(default_factory=dict)
    per_frame: tuple[float, ...] = ()
    ms: float = math.nan
    reason: str | None = None
    seconds: float = 0.0
    frame_metrics: tuple[Mapping[str, float], ...] = ()

    @property
    def ok(self) -> bool:
        return self.status == OK


def failed(fitness: Fitness, reason: str, seconds: float = 0.0) -> Evaluation:
    return Evaluation(FAILED, fitness.worst, reason=reason, seconds=seconds)


#: Fitnesses of the faithful mode (the paper's convention on the WLS map); the others fly.
PAPER_FITNESS = ("mse", "psnr", "ssim", "bad2")
#: Fitnesses that score only what the ranging consumes: WLS smoothing cannot change them.
FLOWN_FITNESS = ("flown", "flown-bad2", "branch")


def _frame_metrics(frame: FrameData, res: DisparityResult, params: StereoParams,
                   convention: str = "bench", score_roi: tuple[float, float, float, float] | None = None,
                   ranging: RangingConfig = FLOWN_RANGING) -> dict[str, float]:
    """Every metric the frame allows (reports), in ``convention`` (metrics.CONVENTIONS).

    bench: the flown map (:func:`flown_map`) inside the scored box; paper: the WLS map, as the paper scores it.
    The box: ``score_roi`` (fractions, as compute.roi) when given, so two files are compared in one box, else
    the candidate's own. Where the frame knows the branch truth: ``branch`` (the plain symmetric error %),
    ``branch_safe`` (the safety-weighted one the flown fitnesses use), ``farther`` (1 when read farther than
    the truth by more than metrics.FARTHER_TOL_PCT, else 0), ``truth_m``, ``branch_m`` (the daemon's ranging,
    NaN when it measured nothing).
    """
    out: dict[str, float] = {}
    if frame.reference is not None:
        box_params = params if score_roi is None else params.replace(**{"compute.roi": tuple(score_roi)})
        box = scored_box(box_params, frame.reference.shape)
        if convention == "bench":
            out.update(bench(frame, flown_map(res, ranging.min_confidence), box))
        else:
            out.update(metrics.score(*metrics.in_box(box, frame.reference, res.disparity)).as_dict())
    if frame.has_branch:
        distance = branch_distance(frame, res, params, ranging)
        truth = frame.branch_distance_m
        out.update(branch=metrics.branch_error(distance, truth), branch_safe=metrics.safe_branch_error(distance, truth),
                   farther=float(metrics.is_farther(distance, truth)), truth_m=float(truth),
                   branch_m=math.nan if distance is None else float(distance))
    return out


def default_convention(fitness: str) -> str:
    """The metric convention a fitness's reports use: the paper's for the paper's fitnesses, else bench."""
    return "paper" if fitness in PAPER_FITNESS else "bench"


def evaluate(params: StereoParams, frames: FrameSet, fitness: Fitness, full: bool = False,
             convention: str | None = None, score_roi: tuple[float, float, float, float] | None = None,
             ranging: RangingConfig = FLOWN_RANGING) -> Evaluation:
    """Score ``params`` on ``frames``, ranged with ``ranging``; never raises for a bad candidate (returns FAILED).

    ``full``: every metric the frames allow, per frame (reports); otherwise the
    fitness alone (the search loop: the pipeline is nearly all of the cost, but
    extra metrics would still add a few % to every evaluation).
    """
    convention = convention or default_convention(fitness.name)
    t_start = time.perf_counter()
    try:
        # A flown evaluation runs what flies (core.disparity.flight_pipeline: no WLS smoothing, the near
        # check the ranging consults); the paper's fitnesses and selfsup score the WLS map.
        flown = fitness.name in FLOWN_FITNESS and convention == "bench"
        pipeline = flight_pipeline(params) if flown else DisparityPipeline(params)
        per_frame, extras, times = [], [], []
        for frame in frames.frames:
            t0 = time.perf_counter()
            with warnings.catch_warnings():  # the warning becomes the failure's reason below
                warnings.simplefilter("ignore", ParameterWarning)
                res = pipeline.run(frame.left, frame.right)
            times.append((time.perf_counter() - t0) * 1000.0)
            if res.warning is not None:
                return failed(fitness, f"{frame.key}: {res.warning}", time.perf_counter() - t_start)
            if not np.isfinite(res.disparity).any():
                return failed(fitness, f"{frame.key}: no valid pixel", time.perf_counter() - t_start)
            value = float(fitness.score(frame, res, params, ranging))
            if math.isnan(value):
                return failed(fitness, f"{frame.key}: {fitness.name} is NaN", time.perf_counter() - t_start)
            per_frame.append(value)
            if full:
                extras.append(_frame_metrics(frame, res, params, convention, score_roi, ranging))
    except Exception as exc:  # a candidate that raises is a failed trial; the run goes on
        return failed(fitness, f"{type(exc).__name__}: {exc}", time.perf_counter() - t_start)
    names = sorted(set().union(*extras)) if extras else []
    mean = {k: float(np.mean([e[k] for e in extras if k in e])) for k in names}
    per = tuple({"id": f.key, "ms": t, **e} for f, e, t in zip(frames.frames, extras, times)) if full else ()
    return Evaluation(OK, float(np.mean(per_frame)), mean, tuple(per_frame), float(np.mean(times)),
                      seconds=time.perf_counter() - t_start, frame_metrics=per)


@dataclass(frozen=True)
class Task:
    """One unit of work for an executor: a candidate (as its parameter dict) on a named frame set.

    ``reading``: instead of scoring, read each frame as the daemon flies (:func:`branch_distances`): the
    evaluation's ``per_frame`` holds the distances in m, NaN where it measured nothing (the safety sweep)."""

    params: Mapping[str, Any]
    frameset: str = "train"
    full: bool = False
    convention: str | None = None     # None: the fitness's own (default_convention)
    reading: bool = False


def read_frames(params: StereoParams, frames: FrameSet, fitness: Fitness, ranging: RangingConfig) -> Evaluation:
    """:func:`branch_distances` as an evaluation (per_frame: m, NaN for no distance); FAILED when it raises."""
    t0 = time.perf_counter()
    try:
        distances = branch_distances(params, frames, ranging)
    except Exception as exc:  # a candidate that raises is refused with its reason, the run goes on
        return failed(fitness, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)
    return Evaluation(OK, math.nan, per_frame=tuple(math.nan if d is None else float(d) for d in distances),
                      seconds=time.perf_counter() - t0)


class Objective:
    """What a worker holds: the frame sets (loaded once), the fitness and the ranging settings it ranges with.
    Call with a :class:`Task`."""

    def __init__(self, framesets: Mapping[str, FrameSet], fitness: str, ranging: RangingConfig = FLOWN_RANGING):
        self.framesets = dict(framesets)
        self.fitness = FITNESS[fitness]
        self.ranging = ranging

    def __call__(self, task: Task) -> Evaluation:
        try:
            params = params_from_dict(task.params)
        except Exception as exc:
            return failed(self.fitness, f"{type(exc).__name__}: {exc}")
        frames = self.framesets[task.frameset]
        if task.reading:
            return read_frames(params, frames, self.fitness, self.ranging)
        return evaluate(params, frames, self.fitness, task.full, task.convention, ranging=self.ranging)
