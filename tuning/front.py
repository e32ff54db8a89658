"""The Pareto front of fitness against frame time, and the choice under a frame-time budget (``--max-ms``).

The search's own timings come from busy workers and are only a guide: :func:`choose_under_budget` re-times
the front here, side by side, and chooses on those times.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.params import StereoParams, params_from_dict

from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.objective import FITNESS, OK
from uav_depth.tuning.store import RunStore


def pareto_front(points: Sequence[tuple[float, float, Any]]) -> list[tuple[float, float, Any]]:
    """Non-dominated (utility, ms, item) points (larger utility, smaller ms), fastest first."""
    front: list[tuple[float, float, Any]] = []
    best = -math.inf
    for u, ms, item in sorted(points, key=lambda p: (p[1], -p[0])):
        if u > best:
            front.append((u, ms, item))
            best = u
    return front


def search_front(store: RunStore, fitness_name: str) -> list[dict[str, Any]]:
    """Pareto front of (fitness, ms per frame) over every stored evaluation, with the search's own timings."""
    fitness = FITNESS[fitness_name]
    pts = [(fitness.utility(ev.value), ev.ms, (key, ev)) for key, params, ev in store.evaluations()
           if ev.status == OK and math.isfinite(ev.ms) and not params.get("invalid")]
    return [{"key": key, "value": ev.value, "ms": ms} for _, ms, (key, ev) in pareto_front(pts)]


def time_params(params: StereoParams, frames: FrameSet, repeats: int = 3) -> float:
    """Median over ``repeats`` of the mean ms per frame of what flies (``flight_pipeline``: no WLS
    smoothing), in this process with OpenCV's default threads (how the daemon runs it)."""
    pipe = flight_pipeline(params)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for f in frames.frames:
            pipe.run(f.left, f.right)
        samples.append((time.perf_counter() - t0) * 1000.0 / max(1, len(frames)))
    return float(statistics.median(samples))


@dataclass(frozen=True)
class BudgetChoice:
    params: StereoParams | None
    value: float
    ms: float
    front: list[dict[str, Any]]
    reason: str | None = None


def choose_under_budget(store: RunStore, fitness_name: str, frames: FrameSet, max_ms: float,
                        max_points: int = 12) -> BudgetChoice:
    """The best stored candidate whose re-timed frame time is within ``max_ms``.

    The search's own timings come from busy workers and are only a guide: the
    Pareto front of (fitness, ms) over every stored evaluation is re-timed here,
    side by side, and the choice is made on those times.
    """
    fitness = FITNESS[fitness_name]
    pts = [(fitness.utility(ev.value), ev.ms, (key, params, ev)) for key, params, ev in store.evaluations()
           if ev.status == OK and math.isfinite(ev.ms) and not params.get("invalid")]
    front = pareto_front(pts)
    if len(front) > max_points:  # keep the extremes and an even spread between
        idx = np.unique(np.linspace(0, len(front) - 1, max_points).round().astype(int))
        front = [front[i] for i in idx]
    timed = []
    for u, ms, (key, params, ev) in front:
        p = params_from_dict(params)
        timed.append({"key": key, "value": ev.value, "search_ms": ms, "ms": time_params(p, frames), "params": params})
    fits = [t for t in timed if t["ms"] <= max_ms]
    if not fits:
        fastest = min((t["ms"] for t in timed), default=math.nan)
        return BudgetChoice(None, math.nan, math.nan, timed,
                            f"no evaluated candidate runs within {max_ms:g} ms per frame (fastest {fastest:.0f} ms)")
    best = max(fits, key=lambda t: fitness.utility(t["value"]))
    return BudgetChoice(params_from_dict(best["params"]), best["value"], best["ms"], timed)
