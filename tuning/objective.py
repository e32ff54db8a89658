"""Fitness metrics and the evaluation of one candidate (a *trial*).

Evaluating a candidate = ``DisparityPipeline(params).run`` on every frame, each
result scored by the fitness metric, averaged over the frames. A candidate that
raises, or leaves a frame without a single valid pixel, is a FAILED evaluation
with its reason and the worst fitness; it never stops a run.

:data:`FITNESS` is the registry (name -> :class:`Fitness`); the CLI's
``--metric`` choices are its keys.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from uav_depth.core.disparity import DisparityPipeline, DisparityResult
from uav_depth.core.errors import ParameterWarning
from uav_depth.core.params import StereoParams, params_from_dict

from uav_depth.tuning import metrics
from uav_depth.tuning.frames import FrameData, FrameSet

OK, FAILED = "ok", "failed"


@dataclass(frozen=True)
class Fitness:
    """One fitness metric: per-frame score of a pipeline result.

    ``direction``: +1 larger is better, -1 smaller is better. ``needs``: what a
    frame must have to be scored ("reference", "branch").
    """

    name: str
    direction: int
    needs: tuple[str, ...]
    score: Callable[[FrameData, DisparityResult, StereoParams], float]
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


def _ref(fn: Callable[[np.ndarray, np.ndarray], float]) -> Callable[[FrameData, DisparityResult, StereoParams], float]:
    return lambda frame, res, params: fn(*metrics.in_box(scored_box(params, frame.reference.shape),
                                                         frame.reference, res.disparity))


def branch_measurement(frame: FrameData, res: DisparityResult, params: StereoParams) -> tuple[float | None, float]:
    """The daemon's own ranging stage on this result: (distance m or None, error % against the frame's truth)."""
    from uav_depth.core.calibration import Calibration
    from uav_depth.daemon.ranging import RangingConfig
    from uav_depth.daemon.ranging import Ranger, resolve_roi

    h, w = frame.left.shape[:2]
    cal = Calibration(focal_px=frame.focal_px, baseline_m=frame.baseline_m, width=w, height=h)
    roi = resolve_roi(frame.roi, w, h)
    m = Ranger(RangingConfig(roi=roi), cal, roi, params).measure(res)
    return m.distance_m, metrics.branch_error(m.distance_m, frame.branch_distance_m)


def _branch(frame: FrameData, res: DisparityResult, params: StereoParams) -> float:
    """The daemon's own ranging stage on this result, against the frame's truth."""
    return branch_measurement(frame, res, params)[1]


def _selfsup(frame: FrameData, res: DisparityResult, params: StereoParams) -> float:
    # Implemented by the reference-disparity work (issue 7); imported lazily so the
    # tuner runs without it for every other metric.
    from uav_depth.tuning.selfsup import selfsup_loss

    return float(selfsup_loss(frame.left, frame.right, res.disparity, box=scored_box(params, frame.left.shape)))


FITNESS: dict[str, Fitness] = {
    "mse": Fitness("mse", -1, ("reference",), _ref(metrics.mse), "mean squared disparity error, px^2"),
    "psnr": Fitness("psnr", +1, ("reference",), _ref(metrics.psnr), "peak signal-to-noise ratio, dB"),
    "ssim": Fitness("ssim", +1, ("reference",), _ref(metrics.ssim), "structural similarity, 0..1"),
    "bad2": Fitness("bad2", -1, ("reference",), _ref(lambda r, e: metrics.bad(r, e, 2.0)),
                    "% of reference pixels off by more than 2 px"),
    "branch": Fitness("branch", -1, ("branch",), _branch,
                      "relative error of the daemon's branch distance (its ranging stage) against the truth, %"),
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


def _frame_metrics(frame: FrameData, res: DisparityResult, params: StereoParams) -> dict[str, float]:
    """Every metric the frame allows (reports)."""
    out: dict[str, float] = {}
    if frame.reference is not None:
        box = scored_box(params, frame.reference.shape)
        out.update(metrics.score(*metrics.in_box(box, frame.reference, res.disparity)).as_dict())
    if frame.has_branch:
        out["branch"] = _branch(frame, res, params)
    return out


def evaluate(params: StereoParams, frames: FrameSet, fitness: Fitness, full: bool = False) -> Evaluation:
    """Score ``params`` on ``frames``; never raises for a bad candidate (returns FAILED).

    ``full``: every metric the frames allow, per frame (reports); otherwise the
    fitness alone (the search loop: the pipeline is nearly all of the cost, but
    extra metrics would still add a few % to every evaluation).
    """
    t_start = time.perf_counter()
    try:
        pipeline = DisparityPipeline(params)
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
            value = float(fitness.score(frame, res, params))
            if math.isnan(value):
                return failed(fitness, f"{frame.key}: {fitness.name} is NaN", time.perf_counter() - t_start)
            per_frame.append(value)
            if full:
                extras.append(_frame_metrics(frame, res, params))
    except Exception as exc:  # a candidate that raises is a failed trial; the run goes on
        return failed(fitness, f"{type(exc).__name__}: {exc}", time.perf_counter() - t_start)
    names = sorted(set().union(*extras)) if extras else []
    mean = {k: float(np.mean([e[k] for e in extras if k in e])) for k in names}
    per = tuple({"id": f.key, "ms": t, **e} for f, e, t in zip(frames.frames, extras, times)) if full else ()
    return Evaluation(OK, float(np.mean(per_frame)), mean, tuple(per_frame), float(np.mean(times)),
                      seconds=time.perf_counter() - t_start, frame_metrics=per)


@dataclass(frozen=True)
class Task:
    """One unit of work for an executor: a candidate (as its parameter dict) on a named frame set."""

    params: Mapping[str, Any]
    frameset: str = "train"
    full: bool = False


class Objective:
    """What a worker holds: the frame sets (loaded once) and the fitness. Call with a :class:`Task`."""

    def __init__(self, framesets: Mapping[str, FrameSet], fitness: str):
        self.framesets = dict(framesets)
        self.fitness = FITNESS[fitness]

    def __call__(self, task: Task) -> Evaluation:
        try:
            params = params_from_dict(task.params)
        except Exception as exc:
            return failed(self.fitness, f"{type(exc).__name__}: {exc}")
        return evaluate(params, self.framesets[task.frameset], self.fitness, task.full)
