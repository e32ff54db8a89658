"""Rectification from K, D, R, T (OpenCV), or a pass-through for rectified sources."""

import math

import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.core.ranging import RangingConfig, Ranger, default_roi
from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import CalibrationError, FrameError
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.core.rectify import Rectifier
from uav_depth.sim.scene import Pose, Scene, SceneConfig

F, B, W, H = 350.0, 0.063, 640, 360


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def raw(r=np.eye(3), t=(-B, 0.0, 0.0), d=(0.0,) * 5):
    k = ((F, 0.0, (W - 1) / 2), (0.0, F, (H - 1) / 2), (0.0, 0.0, 1.0))
    return Calibration(focal_px=F, baseline_m=B, width=W, height=H, k_left=k, d_left=d, k_right=k, d_right=d,
                       r=tuple(map(tuple, r)), t=t)


def test_rectified_calibration_passes_frames_through():
    calib = Calibration(focal_px=F, baseline_m=B, width=W, height=H)
    rect = Rectifier(calib)
    left, right = np.zeros((H, W), np.uint8), np.ones((H, W), np.uint8)
    assert rect.passthrough and rect.calibration is calib
    out = rect(left, right)
    assert out[0] is left and out[1] is right


def test_ideal_raw_rig_keeps_focal_and_baseline():
    rect = Rectifier(raw())
    assert not rect.passthrough
    assert rect.calibration.focal_px == pytest.approx(F, rel=1e-3)
    assert rect.calibration.baseline_m == pytest.approx(B, rel=1e-6)


def test_a_toed_in_right_camera_is_rectified_and_ranged():
    """Render the right eye rotated by 2 degrees about y, rectify with R, T and range the branch."""
    cfg = SceneConfig(width=W, height=H, focal_px=F, baseline_m=B, branch_distance_m=0.8, seed=3, noise_std=1.0)
    scene = Scene(cfg)
    rng = np.random.default_rng(0)
    left = scene.render(Pose(), rng).left
    rot = rot_y(math.radians(2.0))                     # right camera axes (columns) in the left camera frame
    centre = np.array([B, 0.0, 0.0])
    right = scene.render(Pose(rot, centre), rng).left   # the left view of a rig placed at the right eye
    # OpenCV's R, T map left-camera points into the right camera: X_r = R X_l + T.
    calib = raw(r=rot.T, t=tuple(-rot.T @ centre))
    rect = Rectifier(calib)
    rl, rr = rect(left, right)
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
    # The confident reading checks the rectification; the thin guard (docs/ranging.md) reads this branch's
    # edge 4.5 % nearer, which says nothing about the rows lining up.
    m = Ranger(RangingConfig(thin_guard_m2=0.0), rect.calibration, default_roi(W, H), params).measure(
        DisparityPipeline(params).run(rl, rr))
    assert m.valid, m.reason
    assert m.distance_m == pytest.approx(0.8, rel=0.04)
    # without rectification the 2-degree toe-in shifts everything by about f*tan(2 deg) = 12 px
    m_raw = Ranger(RangingConfig(), Calibration(focal_px=F, baseline_m=B, width=W, height=H), default_roi(W, H),
                   params).measure(DisparityPipeline(params).run(left, right))
    assert not m_raw.valid or abs(m_raw.distance_m - 0.8) > 0.1


def test_swapped_or_vertical_cameras_are_refused():
    with pytest.raises(CalibrationError, match="right camera must be at \\+x of the left one"):
        Rectifier(raw(t=(B, 0.0, 0.0)))
    with pytest.raises(CalibrationError, match="side by side"):
        Rectifier(raw(t=(0.0, -B, 0.0)))


def test_frames_of_the_wrong_size_are_refused():
    with pytest.raises(FrameError, match="frames are 320x240 but the calibration is for 640x360"):
        Rectifier(raw())(np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8))
