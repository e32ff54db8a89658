"""Tuner fixtures: tiny synthetic frames and sessions, so a whole tuning run takes a second or two."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.sim.scene import Scene, SceneConfig, write_session
from uav_depth.tuning.frames import FrameData, FrameSet

TINY = dict(width=256, height=192, focal_px=160.0)
#: Tiny images need a smaller disparity range than the 1280x720 baseline's 128.
TINY_BASE = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 48})


@functools.lru_cache(maxsize=None)
def _tiny_frames(n: int, seed: int) -> FrameSet:
    frames = []
    for i in range(n):
        cfg = SceneConfig(**TINY, seed=seed + i, branch_distance_m=0.6 + 0.2 * i)
        f = Scene(cfg).render(rng=np.random.default_rng([seed, i]))
        roi = cfg.center_roi
        frames.append(FrameData(f"tiny/{i:06d}", f.left, f.right, f.disparity, f.branch_mask,
                                f.nearest_branch_distance(roi), roi, cfg.focal_px, cfg.baseline_m))
    return FrameSet("train", tuple(frames))


@pytest.fixture
def tiny_frames() -> FrameSet:
    """Two 256x192 synthetic frames with reference, branch mask and truth."""
    return _tiny_frames(2, 7)


@pytest.fixture(scope="session")
def tiny_session(tmp_path_factory):
    """A 4-frame 256x192 synthetic session on disk (log layout) and a base parameter file for it."""
    from uav_depth.core.params import save_params

    root = tmp_path_factory.mktemp("tune")
    write_session(root / "s", 4, 5, SceneConfig(**TINY))
    save_params(TINY_BASE, root / "base.yaml")
    return root


@pytest.fixture(scope="session", autouse=True)
def sweep_cache(tmp_path_factory):
    """tune keeps its rendered safety sweep in the user's cache ($XDG_CACHE_HOME); the tests' runs (and their
    subprocesses) share one of their own, so a sweep at the tiny rig is rendered once per test session."""
    import os

    saved = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("cache"))
    yield os.environ["XDG_CACHE_HOME"]
    if saved is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = saved
