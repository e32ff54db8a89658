"""Near sweeps: one branch placed at a list of distances, from inside a rig's minimum range to its working
distance, in three scene variants. ``bench/near_sweep.py`` measures both parameter files on them, and
``uav-depth tune`` checks candidates on one (:data:`SWEEPS`, its safety sweep) at the rig of the log it tuned
on.

Variants: ``plain`` (a lone 3 cm branch: inside the minimum range it must read too close, never farther),
``varied`` (:func:`~uav_depth.sim.scene.vary`: imaging conditions and geometry drawn per seed) and ``leafy``
(``SceneConfig.leafy``: twigs, needles and a small branch in front, sky, shadows, the eyes' differences). The
truth of a frame is the nearest significant object in its centre region (:mod:`uav_depth.sim.truth`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np

from uav_depth.sim.frame import StereoFrame
from uav_depth.sim.scene import Scene, SceneConfig, vary

VARIANTS: dict[str, Callable[[float, int], SceneConfig]] = {
    "plain": lambda d, seed: SceneConfig(seed=seed, branch_distance_m=d, branch_radius_m=0.03),
    "varied": lambda d, seed: vary(SceneConfig(), np.random.default_rng([seed, 101]), branch_distance_m=d),
    "leafy": lambda d, seed: SceneConfig.leafy(seed=seed, branch_distance_m=d),
}
#: The quick sweep: inside the minimum range of both shipped files (0.05-0.27 m), across it, and out to 3 m.
QUICK_DISTANCES = (0.05, 0.10, 0.15, 0.20, 0.25, 0.27, 0.29, 0.32, 0.40, 0.60, 1.00, 1.50, 2.00, 3.00)
QUICK_SEEDS = (0, 1)
#: The safety sweep ``uav-depth tune`` checks candidates on by default: the quick sweep's distances inside and
#: across the minimum range, then every 20 cm from 0.4 to 3 m (where twigs in front are read farther), five seeds
#: the benchmarks do not use (bench/near_sweep.py: 0-9), so the near sweep stays a check the tuner never saw.
#: 330 frames, because the quick sweep's 84 are too few to tell a candidate that reads far more leafy frames
#: farther than the flight file (104 against 60 on the 1 cm near sweep) from the flight file (docs/tuning.md).
SAFETY_DISTANCES = QUICK_DISTANCES[:8] + tuple(round(0.4 + 0.2 * i, 2) for i in range(14))
SAFETY_SEEDS = (10, 11, 12, 13, 14)


def at_rig(cfg: SceneConfig, width: int, height: int, focal_px: float, baseline_m: float) -> SceneConfig:
    """``cfg`` seen by another camera: the same scene in metres, that image size, focal length and baseline."""
    return replace(cfg, width=int(width), height=int(height), focal_px=float(focal_px), baseline_m=float(baseline_m))


def sweep_at(distances: tuple[float, ...], seeds: tuple[int, ...], width: int | None = None,
             height: int | None = None, focal_px: float | None = None,
             baseline_m: float | None = None) -> Iterator[tuple[str, SceneConfig]]:
    """(key, scene) of every variant, seed and distance, at the given rig (each value defaults to SceneConfig's)."""
    default = SceneConfig()
    rig = (width or default.width, height or default.height, focal_px or default.focal_px,
           baseline_m or default.baseline_m)
    for variant, make in VARIANTS.items():
        for seed in seeds:
            for d in distances:
                yield f"{variant}-s{seed}-{d:.2f}m", at_rig(make(d, seed), *rig)


def quick_sweep(width: int | None = None, height: int | None = None, focal_px: float | None = None,
                baseline_m: float | None = None) -> Iterator[tuple[str, SceneConfig]]:
    """(key, scene) of the quick sweep (QUICK_DISTANCES x QUICK_SEEDS, 84 frames) at the given rig."""
    return sweep_at(QUICK_DISTANCES, QUICK_SEEDS, width, height, focal_px, baseline_m)


def safety_sweep(width: int | None = None, height: int | None = None, focal_px: float | None = None,
                 baseline_m: float | None = None) -> Iterator[tuple[str, SceneConfig]]:
    """(key, scene) of the safety sweep (SAFETY_DISTANCES x SAFETY_SEEDS, 330 frames) at the given rig."""
    return sweep_at(SAFETY_DISTANCES, SAFETY_SEEDS, width, height, focal_px, baseline_m)


#: The sweeps ``uav-depth tune --safety-sweep`` offers, by name.
SWEEPS = {"standard": safety_sweep, "quick": quick_sweep}

#: The search guide: what tune's search reads its candidates on while it searches, so that it looks where the
#: safety sweep will pass (docs/tuning.md, *The search guide*). Every 20 cm from 0.4 to 3 m, where candidates fail
#: the sweep on the rigs of bench/new_rig.py: leafy scenes on three seeds (nearly every sweep frame a candidate read
#: farther than the base was a leafy one), plain and varied ones on one (a median error the sweep's accuracy rule
#: refuses shows on a few frames). Seeds 20-22, neither the safety sweep's (10-14) nor the benchmarks' (0-9), so
#: the gate's sweep stays a check of frames the search was not led by. 70 frames.
GUIDE_DISTANCES = SAFETY_DISTANCES[8:]
GUIDE_SEEDS = {"plain": (20,), "varied": (20,), "leafy": (20, 21, 22)}


def search_guide(width: int | None = None, height: int | None = None, focal_px: float | None = None,
                 baseline_m: float | None = None) -> Iterator[tuple[str, SceneConfig]]:
    """(key, scene) of the search guide (GUIDE_DISTANCES x GUIDE_SEEDS per variant, 70 frames) at the given rig."""
    for variant, seeds in GUIDE_SEEDS.items():
        yield from (item for item in sweep_at(GUIDE_DISTANCES, seeds, width, height, focal_px, baseline_m)
                    if item[0].startswith(f"{variant}-"))


#: Every sweep tune renders at a log's rig, by name: the safety sweeps and the search guide.
RENDERED = {**SWEEPS, "guide": search_guide}


def render(cfg: SceneConfig) -> StereoFrame:
    """``cfg`` at the identity pose, its noise seeded by its seed: the same frame in every benchmark and in
    tune's safety sweep."""
    return Scene(cfg).render(rng=np.random.default_rng([cfg.seed, 0]))


def render_with_truth(cfg: SceneConfig) -> tuple[np.ndarray, np.ndarray, float, tuple[int, int, int, int]]:
    """(left, right, truth m, centre region px) of :func:`render` (``cfg``)."""
    frame = render(cfg)
    roi = cfg.center_roi
    return frame.left, frame.right, float(frame.truth(roi).significant_m), roi
