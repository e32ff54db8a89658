"""Shared fixtures: small synthetic stereo pairs with known disparity, the motorcycle pair."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from uav_depth.sim.scene import Scene, SceneConfig


@functools.lru_cache(maxsize=None)
def _small_frame(seed: int, distance: float):
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=distance, seed=seed,
                      branch_radius_m=0.04)
    return cfg, Scene(cfg).render(rng=np.random.default_rng(seed))


@pytest.fixture
def small_frame():
    """(SceneConfig, StereoFrame) 320x240 with the branch at 1 m."""
    return _small_frame(1, 1.0)


@functools.lru_cache(maxsize=None)
def _motorcycle():
    import cv2
    from skimage import data

    left, right, gt = data.stereo_motorcycle()
    return (cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR), gt.astype(np.float32))


@pytest.fixture
def motorcycle():
    """scikit-image's Middlebury 2014 motorcycle pair (BGR) and its ground truth."""
    return _motorcycle()


@pytest.fixture
def rx():
    """A real pymavlink endpoint on loopback, standing in for the flight controller."""
    from mavlink_peer import Receiver

    r = Receiver()
    yield r
    r.close()
