"""Daemon-side benchmark: the flown pipeline against OpenCV's sample pipeline, side by side.

Frames are synthetic scenes (:mod:`uav_depth.sim.scene`) with the branch at
known distances, rendered before any timing. Every pipeline runs on the same
frames, interleaved frame by frame and round by round, so that whatever else
the machine is doing slows them alike and their ratio stays meaningful.

One timed step is what the daemon does per frame after capture: the disparity
pipeline (its stages timed by :class:`DisparityResult.timings_ms`) and the
branch ranging (:class:`uav_depth.core.ranging.Ranger`). Capture, MAVLink
and the daemon's threads are not in it; their latency is the daemon's own.
Benchmarks print numbers; nothing here asserts a time.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from uav_depth.cli.progress import QUIET, Progress
from uav_depth.core.disparity import FAITHFUL, MEASURED, DisparityPipeline, DisparityResult, flight_pipeline
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams
from uav_depth.core.params.flight import flight_working_distance_m
from uav_depth.sim.scene import Scene, SceneConfig, background_period_px, vary


@dataclass(frozen=True)
class BenchFrame:
    """One pre-rendered pair with its truth: nearest branch surface in the centre third, m,
    and the exact (H, W) float32 left disparity, px."""

    left: np.ndarray
    right: np.ndarray
    truth_m: float
    design_m: float
    scene: SceneConfig
    disparity: np.ndarray


@dataclass(frozen=True)
class Variant:
    """A pipeline to time: its parameters, how many rounds, and OpenCV's thread count (None: leave it).

    ``flies``: time it as the daemon flies it (:func:`flight_pipeline`: no WLS smoothing, near check
    on), else as the tuner's faithful mode computes it (every stage, WLS included).
    """

    name: str
    params: StereoParams
    rounds: int
    threads: int | None = None
    note: str = ""
    flies: bool = False
    smooth: bool = True     # not flies: run the WLS smoothing (False: the WLS lever alone, no near check)


@dataclass
class VariantResult:
    """Everything measured for one variant (times in ms, errors relative: (estimate - truth) / truth)."""

    variant: Variant
    total_ms: list[float] = field(default_factory=list)
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    estimates_m: list[float | None] = field(default_factory=list)

    def summary(self, frames: Sequence[BenchFrame], naive_median_ms: float | None,
                exact_m: Sequence[float | None] = (), max_distance_m: float = 2.0) -> dict[str, Any]:
        """``exact_m``: the ranging's estimate on exact disparity per frame (see :func:`ranging_floor`)."""
        t = np.asarray(self.total_ms)
        errs = [None if e is None else (e - f.truth_m) / f.truth_m for e, f in zip(self.estimates_m, frames)]
        # Frames placed up to max_distance_m (the truth is a hair beyond where pixel centres miss the ridge).
        near = [f.design_m <= max_distance_m + 1e-9 for f in frames]
        within = [abs(e) for e, n in zip(errs, near) if e is not None and n]
        missing = sum(1 for e, n in zip(errs, near) if e is None and n)
        # What the disparity pipeline adds: its estimate against the same ranging on exact disparity.
        vs_exact = [abs(e - x) / x for e, x, n in zip(self.estimates_m, exact_m, near)
                    if e is not None and x is not None and n]
        med = float(np.median(t))
        return {
            "name": self.variant.name,
            "note": self.variant.note,
            "threads": self.variant.threads,
            "params": self.variant.params.to_dict(),
            "params_hash": self.variant.params.hash(),
            "runs": int(t.size),
            "median_ms": med,
            "p99_ms": float(np.percentile(t, 99)),
            "mean_ms": float(t.mean()),
            "fps": 1000.0 / med,
            "fps_sustained": 1000.0 * t.size / float(t.sum()),
            "speedup_vs_naive": (naive_median_ms / med) if naive_median_ms else None,
            "stages_median_ms": {k: float(np.median(v)) for k, v in self.stages_ms.items()},
            "max_abs_rel_error": max(within) if within else None,
            "median_abs_rel_error": float(np.median(within)) if within else None,
            "frames_without_estimate": missing,
            "max_abs_rel_vs_exact": max(vs_exact) if vs_exact else None,
            "per_frame": [{"truth_m": f.truth_m, "estimate_m": e, "rel_error": r}
                          for f, e, r in zip(frames, self.estimates_m, errs)],
        }


def machine() -> dict[str, Any]:
    """Where the figures come from: CPU model, cores usable, OpenCV build and threads."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 0
    return {"cpu": model, "cores": os.cpu_count(), "cores_usable": usable, "python": platform.python_version(),
            "numpy": np.__version__, "opencv": cv2.__version__, "opencv_threads": cv2.getNumThreads(),
            "platform": platform.platform()}


def machine_line(m: dict[str, Any] | None = None) -> str:
    """:func:`machine` as one line for printed figures, with the load average (figures here are noisy)."""
    m = m or machine()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"machine: {m['cores']} cores ({m['cores_usable']} usable), {m['cpu']}; load average {load:.1f}; "
            f"Python {m['python']}, OpenCV {m['opencv']} ({m['opencv_threads']} threads), numpy {m['numpy']}")


#: Smallest image period of the background texture the benchmark allows, as a fraction of the
#: image width (200 px at 1280): beyond the widest search any variant uses (160 px for 0.3 m).
MIN_BACKGROUND_PERIOD = 200 / 1280


def make_frames(n: int = 12, width: int = 1280, height: int = 720, seed: int = 0,
                distances_m: tuple[float, float] = (0.5, 2.0), color: bool = True,
                progress: Callable[[int, int], None] | None = None) -> list[BenchFrame]:
    """``n`` varied scenes with the branch at evenly spaced distances; colour as a camera gives it.

    The focal length follows the width (700 px at 1280, ZED Mini-like), so every
    size sees the same field of view. A scene whose background texture would
    repeat inside the search range (see :func:`scene.background_period_px`) gets
    its background moved nearer, so a false match one tile away cannot pass for
    the branch: the benchmark judges the pipeline, not the renderer's tiling.
    ``progress(done, n)`` after each pair.
    """
    rng = np.random.default_rng(seed)
    base = SceneConfig(width=width, height=height, focal_px=700.0 * width / 1280.0, color=color)
    min_period = MIN_BACKGROUND_PERIOD * width
    out = []
    for d in np.linspace(distances_m[0], distances_m[1], n):
        cfg = vary(base, rng, branch_distance_m=float(d))
        if background_period_px(cfg) < min_period:
            farthest = cfg.background_distance_m * background_period_px(cfg) / min_period
            nearest = cfg.branch_distance_m + cfg.trunk_offset_m + 1.0
            cfg = dc_replace(cfg, background_distance_m=float(rng.uniform(max(nearest, 0.6 * farthest),
                                                                          max(nearest, farthest))))
        frame = Scene(cfg).render(rng=rng)
        out.append(BenchFrame(frame.left, frame.right, frame.nearest_branch_distance(cfg.center_roi), float(d), cfg,
                              frame.disparity))
        if progress is not None:
            progress(len(out), n)
    return out


#: OpenCV's sample rule for P1 / P2 per block pixel, one channel (samples/python/stereo_match.py multiplies by 3).
OPENCV_P1_PER_BLOCK_PX = 8
OPENCV_P2_PER_BLOCK_PX = 32


def lever_variants(flight: StereoParams, rounds: int, naive_rounds: int) -> list[Variant]:
    """The naive pipeline, then one lever added at a time up to ``flight``'s settings.

    Grey matching takes P1/P2 from OpenCV's sample rule for one channel
    (8 and 32 x block_size^2) instead of three.
    """
    roi = flight.compute.roi
    mid = max(2, (rounds + naive_rounds) // 4)
    bs = DEFAULT_PARAMS.sgbm.block_size
    steps: list[tuple[str, dict[str, Any], int, str]] = [
        ("+roi", {"compute.roi": list(roi)}, mid, "match the ROI plus the search margin only"),
        ("+grey", {"compute.grey": True, "sgbm.p1": OPENCV_P1_PER_BLOCK_PX * bs * bs,
                   "sgbm.p2": OPENCV_P2_PER_BLOCK_PX * bs * bs}, mid,
         "grey matching, P1/P2 for one channel"),
        ("+3way", {"sgbm.mode": "sgbm_3way"}, mid, "SGBM 3-way mode"),
        ("+scale", {"compute.scale": flight.compute.scale,
                    "sgbm.num_disparities": max(16, 16 * round(128 * flight.compute.scale / 16))}, rounds,
         "reduced resolution, same distance range as naive"),
        ("+wls@matched", {"compute.wls_at": flight.compute.wls_at}, rounds,
         "WLS at the matched resolution, then resized"),
    ]
    out = [Variant("naive", DEFAULT_PARAMS, naive_rounds, note="OpenCV sample: full frame, colour, SGBM+right+WLS")]
    p = DEFAULT_PARAMS
    for name, change, r, note in steps:
        p = p.replace(**change)
        out.append(Variant(name, p, r, note=note))
    diff = [f"{k}={v}" for k, v in _flat(flight).items() if _flat(p)[k] != v]
    out.append(Variant("flight+WLS", flight, rounds, note="the flight file as the tuner's faithful mode "
                       "computes it: WLS smoothing, no near check"))
    out.append(Variant("flight", flight, rounds, flies=True,
                       note="as it flies: no WLS smoothing, near check" + (f" ({', '.join(diff)})" if diff else "")))
    out.append(Variant("flight-1thread", flight, rounds, threads=1, flies=True, note="cv2.setNumThreads(1)"))
    out.append(Variant("flight-noWLS", flight.replace(**{"wls.enabled": False}), rounds,
                       note="no right matcher/WLS: no confidence map"))
    return out


def _flat(params: StereoParams) -> dict[str, Any]:
    return {f"{sec}.{k}": v for sec, d in params.to_dict().items() for k, v in d.items()}


def _ranger_factory() -> Callable[[StereoParams, BenchFrame], Callable[[Any], float | None]]:
    """The daemon's own ranging (defaults, centre third) as ``make(params, frame)(result) -> metres``."""
    from uav_depth.core.ranging import Ranger, RangingConfig, default_roi

    cache: dict[tuple[str, int, int], Any] = {}

    def make(params: StereoParams, frame: BenchFrame) -> Callable[[Any], float | None]:
        h, w = frame.left.shape[:2]
        key = (params.hash(), w, h)
        if key not in cache:
            cache[key] = Ranger(RangingConfig(), frame.scene.calibration, default_roi(w, h), params)
        ranger = cache[key]
        return lambda result: ranger.measure(result).distance_m

    return make


def ranging_floor(frames: Sequence[BenchFrame], max_distance_m: float = 2.0) -> dict[str, Any]:
    """The ranging's own error: the exact disparity (every pixel measured, confidence 1) through the
    daemon's ranging. No pipeline can do better than this on these frames."""
    make_ranger = _ranger_factory()
    errs: list[float | None] = []
    ests: list[float | None] = []
    for f in frames:
        d = np.where(np.isfinite(f.disparity), f.disparity, np.nan).astype(np.float32)
        est = make_ranger(DEFAULT_PARAMS, f)(DisparityResult(d, d, np.ones_like(d)))
        ests.append(est)
        errs.append(None if est is None else (est - f.truth_m) / f.truth_m)
    within = [abs(e) for e, f in zip(errs, frames) if e is not None and f.design_m <= max_distance_m + 1e-9]
    return {"max_abs_rel_error": max(within) if within else None,
            "median_abs_rel_error": float(np.median(within)) if within else None, "per_frame_rel_error": errs,
            "per_frame_estimate_m": ests}


def run(frames: Sequence[BenchFrame], variants: Sequence[Variant], progress: Progress = QUIET) -> dict[str, Any]:
    """Time every variant on every frame, interleaved; return the summary (see :meth:`VariantResult.summary`).

    ``progress``: a step line per frame timed (every variant of the round on it) on a terminal."""
    make_ranger = _ranger_factory()
    pipes = {v.name: flight_pipeline(v.params) if v.flies
             else DisparityPipeline(v.params, FAITHFUL if v.smooth else MEASURED) for v in variants}
    results = {v.name: VariantResult(v) for v in variants}
    default_threads = cv2.getNumThreads()
    n_rounds = max(v.rounds for v in variants)
    progress.phase(f"timing {len(variants)} pipelines interleaved, {n_rounds} round(s) over {len(frames)} frames")
    for rnd in range(n_rounds):
        # Rotate the order each round: no variant always runs right after a slow one.
        order = [v for v in variants if rnd < v.rounds]
        order = order[rnd % len(order):] + order[:rnd % len(order)]
        for i, frame in enumerate(frames):
            for v in order:
                if v.threads is not None:
                    cv2.setNumThreads(v.threads)
                measure = make_ranger(v.params, frame)
                t0 = time.perf_counter()
                res = pipes[v.name].run(frame.left, frame.right)
                t1 = time.perf_counter()
                est = measure(res)
                t2 = time.perf_counter()
                if v.threads is not None:
                    cv2.setNumThreads(default_threads)
                r = results[v.name]
                r.total_ms.append((t2 - t0) * 1000.0)
                for k, ms in {**res.timings_ms, "range": (t2 - t1) * 1000.0}.items():
                    r.stages_ms.setdefault(k, []).append(ms)
                if rnd == 0:
                    r.estimates_m.append(est)
            progress.step(f"round {rnd + 1}/{n_rounds}, frames timed", rnd * len(frames) + i + 1,
                          n_rounds * len(frames))
    naive = results.get("naive")
    naive_med = float(np.median(naive.total_ms)) if naive is not None else None
    floor = ranging_floor(frames)
    return {"variants": [r.summary(frames, naive_med, floor["per_frame_estimate_m"]) for r in results.values()],
            "ranging_floor": floor}


def bench(flight: StereoParams, frames: int = 12, rounds: int = 20, naive_rounds: int = 2, width: int = 1280,
          height: int = 720, seed: int = 0, levers: bool = False, threads: int | None = None,
          progress: Progress = QUIET) -> dict[str, Any]:
    """The whole benchmark: render, time naive vs flight (or the lever ladder), report with the machine.

    ``progress``: phase and step lines on a terminal (:mod:`uav_depth.cli.progress`)."""
    if threads is not None:
        cv2.setNumThreads(threads)
    progress.phase(f"rendering {frames} synthetic pairs {width}x{height}")
    t0 = time.perf_counter()
    fr = make_frames(frames, width, height, seed, progress=progress.counter("rendered"))
    render_s = time.perf_counter() - t0
    if levers:
        variants = lever_variants(flight, rounds, naive_rounds)
    else:
        variants = [Variant("naive", DEFAULT_PARAMS, naive_rounds,
                            note="OpenCV sample: full frame, colour, SGBM+right+WLS"),
                    Variant("flight+WLS", flight, rounds, note="the flight file as the tuner's faithful "
                            "mode computes it: WLS smoothing, no near check"),
                    Variant("flight-noSmooth", flight, rounds, smooth=False,
                            note="flight+WLS without the WLS smoothing (the smoothing's saving alone, no near check)"),
                    Variant("flight", flight, rounds, flies=True,
                            note="the flight parameter file as it flies: no WLS smoothing, near check")]
    out = run(fr, variants, progress)
    out["machine"] = machine()
    out["frames"] = {"n": len(fr), "width": width, "height": height, "seed": seed, "colour": True,
                     "truth_m": [f.truth_m for f in fr], "render_s_per_pair": render_s / max(1, len(fr))}
    out["working_distance_m"] = list(flight_working_distance_m())
    return out


def format_report(out: dict[str, Any]) -> str:
    """The human-readable table of :func:`bench`'s result."""
    m, fr = out["machine"], out["frames"]
    lines = [f"machine: {m['cpu']}, {m['cores_usable']} of {m['cores']} cores usable, OpenCV {m['opencv']} "
             f"({m['opencv_threads']} threads), numpy {m['numpy']}",
             f"frames: {fr['n']} synthetic pairs {fr['width']}x{fr['height']} colour, branch "
             f"{min(fr['truth_m']):.2f}..{max(fr['truth_m']):.2f} m (rendered {fr['render_s_per_pair']:.2f} s/pair)",
             "time: disparity pipeline + branch ranging per frame, ms; err: |estimate - truth| / truth over "
             "frames up to 2 m;",
             "vs exact: largest |estimate - estimate on exact disparity| / the latter, the error the pipeline adds "
             "to the ranging's own", ""]
    head = (f"{'variant':16s} {'runs':>5s} {'median':>8s} {'p99':>8s} {'fps':>7s} {'x naive':>8s} "
            f"{'max err':>8s} {'med err':>8s} {'vs exact':>8s} {'miss':>4s}  stages (median ms)")
    lines.append(head)
    lines.append("-" * len(head))
    def pct(x: float | None) -> str:
        return "-" if x is None else f"{100 * x:.2f}%"

    for v in out["variants"]:
        ratio = "-" if v["speedup_vs_naive"] is None else f"{v['speedup_vs_naive']:.1f}"
        stages = " ".join(f"{k} {ms:.1f}" for k, ms in v["stages_median_ms"].items())
        lines.append(f"{v['name']:16s} {v['runs']:5d} {v['median_ms']:8.1f} {v['p99_ms']:8.1f} {v['fps']:7.1f} "
                     f"{ratio:>8s} {pct(v['max_abs_rel_error']):>8s} {pct(v['median_abs_rel_error']):>8s} "
                     f"{pct(v['max_abs_rel_vs_exact']):>8s} {v['frames_without_estimate']:4d}  {stages}")
    floor = out.get("ranging_floor")
    if floor:
        lines.append(f"{'exact disparity':16s} {'':5s} {'':8s} {'':8s} {'':7s} {'':8s} "
                     f"{pct(floor['max_abs_rel_error']):>8s} {pct(floor['median_abs_rel_error']):>8s}       "
                     "(the ranging alone, on ray-cast truth)")
    return "\n".join(lines)


__all__ = ["BenchFrame", "Variant", "bench", "format_report", "lever_variants", "machine", "make_frames", "run"]
