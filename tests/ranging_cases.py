"""The ranging tests' shared cases: a ranger on the test calibration, hand-built results, rendered frames."""

import functools
from pathlib import Path

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityPipeline, DisparityResult
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.core.ranging import Ranger, RangingConfig, Reason, default_roi
from uav_depth.sim.scene import Scene, SceneConfig


PARAMS = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
#: The near check's two rules on the near pass's matches beyond the search (docs/ranging.md, *Too close*, 1 and 3).
NEAR_PASS_RULES = (Reason.NEAR_PASS, Reason.NEAR_UNCONFIRMED)


@functools.lru_cache(maxsize=None)
def _scene_result(distance: float, seed: int):
    cfg = SceneConfig(width=640, height=360, focal_px=350.0, branch_distance_m=distance, seed=seed)
    frame = Scene(cfg).render(rng=np.random.default_rng(seed))
    return cfg, frame, DisparityPipeline(PARAMS).run(frame.left, frame.right)


def ranger(cfg=RangingConfig(), calib=None, roi=None, params=PARAMS):
    calib = calib or Calibration(focal_px=350.0, baseline_m=0.063, width=640, height=360)
    return Ranger(cfg, calib, roi or default_roi(calib.width, calib.height), params)


def _result(measured, disparity=None, confidence=None):
    measured = np.asarray(measured, np.float32)
    return DisparityResult(measured if disparity is None else disparity, measured, confidence)


FLIGHT_FILE = Path(__file__).resolve().parents[1] / "deploy" / "params-flight.yaml"


@functools.lru_cache(maxsize=None)
def _flight_frame(distance: float, seed: int):
    cfg = SceneConfig(seed=seed, branch_distance_m=distance, branch_radius_m=0.03)
    return cfg, Scene(cfg).render(rng=np.random.default_rng(seed))


def _twig_in_front(twig_d: float = 22.05):
    """A wall at 2 m (confident), a 10 x 80 px twig in front at disparity ``twig_d`` whose matches pass the
    left-right check but carry no confidence (all depth edge)."""
    d = np.full((360, 640), 11.025, np.float32)
    conf = np.ones_like(d)
    lr = np.ones(d.shape, bool)
    d[160:170, 250:330] = twig_d
    conf[160:170, 250:330] = 0.1
    return DisparityResult(d, d, conf, lr_consistent=lr), lr
