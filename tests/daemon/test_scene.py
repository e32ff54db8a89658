import numpy as np
import pytest

from uav_depth.daemon.errors import ConfigError
from uav_depth.daemon.scene import Pose, Scene, SceneConfig, render_pair, time_render


def test_same_seed_same_pixels_and_different_seed_differs():
    cfg = SceneConfig(width=160, height=120, focal_px=100.0, seed=5)
    a, b = render_pair(cfg), render_pair(cfg)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    c = render_pair(SceneConfig(width=160, height=120, focal_px=100.0, seed=6))
    assert not np.array_equal(a.left, c.left)


@pytest.mark.parametrize("distance", [0.5, 1.0, 2.0])
def test_branch_distance_and_disparity_are_exact(distance):
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=distance, seed=2)
    f = Scene(cfg).render()
    # nearest surface of the target branch, sampled at pixel centres: within 0.5% of the design distance
    assert f.nearest_branch_distance(cfg.center_roi) == pytest.approx(distance, rel=5e-3)
    ok = np.isfinite(f.depth)
    assert np.allclose(f.disparity[ok] * f.depth[ok], cfg.focal_px * cfg.baseline_m, rtol=1e-5)


def test_right_view_is_the_left_view_shifted_by_disparity():
    """Texture is attached to surfaces: a left pixel at disparity d looks like right pixel x-d."""
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, noise_std=0.0, seed=3)
    f = Scene(cfg).render()
    ys, xs = np.nonzero(f.branch_mask)
    ys, xs = ys[::50], xs[::50]
    xr = np.round(xs - f.disparity[ys, xs]).astype(int)
    inside = xr >= 0
    ys, xs, xr = ys[inside], xs[inside], xr[inside]
    diff = np.abs(f.left[ys, xs].astype(int) - f.right[ys, xr].astype(int))
    assert np.median(diff) <= 6


def test_moving_forward_brings_branch_closer():
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=1.5, seed=4)
    scene = Scene(cfg)
    far = scene.render(Pose.forward(0.0)).nearest_branch_distance(cfg.center_roi)
    near = scene.render(Pose.forward(0.5)).nearest_branch_distance(cfg.center_roi)
    assert near == pytest.approx(far - 0.5, abs=0.01)


def test_imaging_conditions_change_pixels_not_geometry():
    base = SceneConfig(width=160, height=120, focal_px=100.0, seed=1)
    a = render_pair(base)
    for change in ({"brightness": 30.0}, {"contrast": 0.5}, {"noise_std": 8.0}, {"blur_sigma": 1.5},
                   {"texture_scale": 2.0}, {"color": True}):
        b = render_pair(SceneConfig(**{**base.to_dict(), **change}))
        assert not np.array_equal(a.left, b.left[..., 0] if b.left.ndim == 3 else b.left), change
        assert np.array_equal(a.disparity, b.disparity)


@pytest.mark.parametrize("key,value,msg", [("branch_distance_m", 9.0, "less than background_distance_m"),
                                           ("focal_px", 0, "must be greater than 0"),
                                           ("bogus", 1, "is not a known scene key")])
def test_bad_scene_config(key, value, msg):
    with pytest.raises(ConfigError, match=msg):
        SceneConfig.from_dict({key: value})


def test_time_render_reports_seconds():
    assert 0 < time_render(SceneConfig(width=160, height=120, focal_px=100.0), repeats=1) < 60
