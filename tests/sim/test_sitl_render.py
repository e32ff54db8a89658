"""SITL's frames: only what the flight pipeline reads is ray-cast, and a frame is as old as its pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uav_depth.core.params.flight import flight_params
from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.ranging import RangingConfig, Ranger, default_roi
from uav_depth.sim.scene import Pose, Scene, SceneConfig
from uav_depth.sim.sitl import rot_x, rot_y
from uav_depth.sim.source import Config, SyntheticSource, pipeline_reads

W, H, F = 640, 360, 350.0


def tilted(k: float) -> Pose:
    return Pose(rot_x(0.02 * k) @ rot_y(-0.03 * k), np.array([0.05 * k, -0.02, 0.5 + 0.3 * k]))


@pytest.mark.parametrize("cfg", [
    SceneConfig(width=W, height=H, focal_px=F, n_branches=4, seed=1, noise_std=0.0),
    SceneConfig.leafy(seed=3, width=W, height=H, focal_px=F, rect_error_px=0.4, blur_sigma=0.8,
                      right_blur_sigma=0.5, noise_std=0.0),
], ids=["plain", "leafy"])
def test_a_window_render_is_the_full_render_inside_and_blank_outside(cfg):
    scene = Scene(cfg)
    win = (40, 90, 600, 270)
    x0, y0, x1, y1 = win
    for k in (0.0, 1.0):
        full, part = scene.render(tilted(k)), scene.render(tilted(k), window=win)
        for name in ("left", "right", "depth", "labels", "objects", "disparity"):
            a, b = getattr(full, name), getattr(part, name)
            assert a.shape == b.shape
            np.testing.assert_array_equal(b[y0:y1, x0:x1], a[y0:y1, x0:x1], err_msg=name)
        outside = np.ones((H, W), bool)
        outside[y0:y1, x0:x1] = False
        assert not part.left[outside].any() and not part.right[outside].any()
        assert np.isinf(part.depth[outside]).all() and (part.objects[outside] == -1).all()
    with pytest.raises(ValueError, match="must lie inside"):
        scene.render(window=(0, 0, W + 1, H))


def test_the_flight_pipeline_measures_the_same_on_what_it_reads():
    """With the noise off, the pipeline's result and the ranging are identical on a render of only its crops."""
    params = flight_params(focal_px=F, baseline_m=0.063)
    cfg = SceneConfig(width=W, height=H, focal_px=F, n_branches=4, seed=1, noise_std=0.0, branch_distance_m=2.0)
    scene, pipe = Scene(cfg), flight_pipeline(params)
    reads = pipeline_reads(params, W, H)
    assert reads != (0, 0, W, H)          # the point: less than the whole frame
    roi = default_roi(W, H)
    ranger = Ranger(RangingConfig(), cfg.calibration, roi, params)
    for k in (0.0, 1.0):
        full, part = scene.render(tilted(k)), scene.render(tilted(k), window=reads)
        a, b = pipe.run(full.left, full.right), pipe.run(part.left, part.right)
        np.testing.assert_array_equal(a.measured, b.measured)
        np.testing.assert_array_equal(a.confidence, b.confidence)
        np.testing.assert_array_equal(a.near.disparity, b.near.disparity)
        ma, mb = ranger.measure(a), ranger.measure(b)
        assert ma.valid and (ma.distance_m, ma.sigma_m, ma.quality) == (mb.distance_m, mb.sigma_m, mb.quality)
    # ... and a render of less than that changes what it reads (the window is not merely large).
    x0, y0, x1, y1 = reads
    less = scene.render(tilted(0.0), window=(x0 + 8, y0, x1, y1))
    assert not np.array_equal(pipe.run(less.left, less.right).near.disparity,
                              pipe.run(*(lambda f: (f.left, f.right))(scene.render(tilted(0.0)))).near.disparity)


class TimedPose:
    """A pose provider that says when its pose was true (as the SITL pose tracker does)."""

    def __init__(self):
        self.pose_time = None

    def __call__(self, t_s: float) -> Pose:
        return Pose.forward(0.5)


def test_a_sitl_frame_is_as_old_as_its_pose_and_an_old_pose_is_no_new_frame():
    now = [100.0]
    provider = TimedPose()
    provider.pose_time = 99.7
    cfg = Config(scene=SceneConfig(width=160, height=90, focal_px=90.0, seed=2), fps=1000.0)
    src = SyntheticSource(cfg, pose_provider=provider, clock=lambda: now[0])
    src.read_window = lambda: (20, 10, 140, 80)
    src.open()
    frame = src.read(0.01)
    assert frame is not None and frame.t_capture == 99.7         # the pose's time, not the render's
    assert frame.meta["window"] == [min(20, src.truth_roi[0]), min(10, src.truth_roi[1]),
                                    max(140, src.truth_roi[2]), max(80, src.truth_roi[3])]
    now[0] += 0.01
    assert src.read(0.001) is None                                 # the same pose again: nothing new
    provider.pose_time = 100.005
    now[0] += 0.01
    assert src.read(0.01).t_capture == 100.005


class PredictingPose:
    """A pose provider that predicts (as the SITL pose tracker does): the pose for the time asked."""

    predicts = True

    def __init__(self):
        self.pose_time = None
        self.asked: list[float] = []

    def __call__(self, t_s: float, at: float | None = None) -> Pose:
        self.asked.append(at)
        self.pose_time = at
        return Pose.forward(0.5 + 0.01 * len(self.asked))       # a new pose every time: nothing cached


def test_a_predicted_frame_shows_when_its_render_is_done_and_never_arrives_before_that():
    import time
    provider = PredictingPose()
    cfg = Config(scene=SceneConfig(width=160, height=90, focal_px=90.0, seed=2), fps=1000.0)
    src = SyntheticSource(cfg, pose_provider=provider)
    src.open()
    assert src.render_lead_s() == 0.0            # no read rendered yet: nothing to go by
    for i in range(4):
        t_read = time.monotonic()
        lead = src.render_lead_s()
        frame = src.read(0.5)
        delivered = time.monotonic()
        assert frame is not None
        assert provider.asked[-1] == pytest.approx(t_read + lead, abs=0.005)    # asked for render's end
        assert frame.t_capture == provider.asked[-1]                            # stamped with it
        assert delivered >= frame.t_capture                                      # never from the future
        assert (lead > 0) == (i > 0)             # from the second read on, the renders measured so far
