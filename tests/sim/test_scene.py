import numpy as np
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.sim.scene import Pose, Scene, SceneConfig, render_pair, time_render


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


def _turned(deg: float, position) -> Pose:
    th = np.radians(deg)
    rot = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    return Pose(rot, np.asarray(position, dtype=float))


@pytest.mark.parametrize("pose", [Pose(), Pose.forward(0.4), _turned(12.0, [0.1, -0.05, 0.2]),
                                  _turned(-25.0, [-0.2, 0.1, 0.0]), Pose.forward(1.05)],
                         ids=["identity", "forward", "turned-right", "turned-left", "through-branch"])
def test_culled_render_equals_full_frame_cast(monkeypatch, pose):
    """Bounding-volume culling must never drop a hit: same pixels as casting every ray at every cylinder."""
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=1.0, n_branches=6, color=True, seed=9)
    fast = Scene(cfg).render(pose, np.random.default_rng(3))
    monkeypatch.setattr(Scene, "_candidates", lambda self, cyl, o, rot: None)
    full = Scene(cfg).render(pose, np.random.default_rng(3))
    assert fast.branch_mask.any()
    for name in ("left", "right", "labels"):
        assert np.array_equal(getattr(fast, name), getattr(full, name)), name
    assert np.array_equal(fast.depth, full.depth)


def test_rendering_twice_from_one_scene_is_repeatable():
    """Cached ray directions must not leak between poses: A, B, A renders A's pixels again."""
    scene = Scene(SceneConfig(width=160, height=120, focal_px=100.0, seed=2))
    a = scene.render(Pose(), np.random.default_rng(0))
    scene.render(_turned(10.0, [0.0, 0.0, 0.1]), np.random.default_rng(0))
    again = scene.render(Pose(), np.random.default_rng(0))
    assert np.array_equal(a.left, again.left) and np.array_equal(a.depth, again.depth)


def test_texture_wrap_is_numpy_mod_bit_for_bit():
    from uav_depth.sim.scene import _TEX_SIZE, _wrap

    rng = np.random.default_rng(0)
    x = np.concatenate([rng.standard_normal(20000) * s for s in (1e-30, 1.0, 512.0, 1e6, 1e15)]
                       + [np.arange(-2048, 2048, 0.25), np.array([-0.0, 0.0, -512.0, -1e-300, 1023.9999999999999])])
    for dtype in (np.float64, np.float32):
        xs = x.astype(dtype)
        assert np.array_equal(_wrap(xs), np.mod(xs, _TEX_SIZE))


def test_textures_do_not_repeat_inside_a_search_range():
    """A square-laid tile repeated every tile width along a row, and SGBM matched the wrong repeat
    with full confidence (false near branches). The background tile is laid at an irrational angle
    and the bark spirals, so one tile width along a row shows different texture."""
    from uav_depth.sim.scene import background_period_px

    # a square 3 m tile at texture_scale 1.25 and 8.4 m would repeat every 200 px
    cfg = SceneConfig(width=640, height=120, focal_px=700.0, background_distance_m=8.4, texture_scale=1.25,
                      n_branches=0, noise_std=0.0, branch_distance_m=0.5, seed=3)
    assert background_period_px(cfg) == pytest.approx(200.0 * np.sqrt(34.0))
    f = Scene(cfg).render()
    bg = f.labels == 0
    for shift in (200, 100):
        both = bg[:, :-shift] & bg[:, shift:]
        diff = np.abs(f.left[:, :-shift].astype(int) - f.left[:, shift:].astype(int))[both]
        assert np.median(diff) > 5, shift
    # a horizontal branch 0.5 m away: the 0.25 m bark tile would repeat every 350 px
    cfg = SceneConfig(width=1280, height=200, focal_px=700.0, branch_distance_m=0.5, branch_angle_deg=0.0,
                      n_branches=0, noise_std=0.0, seed=3)
    f = Scene(cfg).render()
    row = 100
    br = f.labels[row] == 2

    def median_diff(shift):
        both = br[:-shift] & br[shift:]
        assert both.sum() > 100
        return np.median(np.abs(f.left[row, :-shift].astype(int) - f.left[row, shift:].astype(int))[both])

    # laid straight, the tile period gave nearly identical pixels; now it differs like any other shift
    assert median_diff(350) > 1 and median_diff(350) >= 0.5 * median_diff(173)