from dataclasses import replace

import cv2
import numpy as np
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.sim import scene as scene_module
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
    monkeypatch.setattr(Scene, "CULL", False)
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

# -- what lies in front of the saw, and the rig's flaws --------------------------------------

def _small(**kw):
    base = dict(width=320, height=180, focal_px=175.0, noise_std=0.0, seed=4, branch_distance_m=0.8)
    base.update(kw)
    return SceneConfig(**base)


def test_default_keys_add_nothing_and_leafy_preset_adds_everything():
    from uav_depth.sim.scene import NEEDLE, SKY, TWIG

    plain = Scene(_small())
    assert len(plain.cylinders) == 1 + 1 + plain.config.n_branches        # trunk, target, others
    f = plain.render()
    assert set(np.unique(f.labels)) <= {0, 1, 2}
    leafy = SceneConfig.leafy(seed=4, width=320, height=180, focal_px=175.0, branch_distance_m=0.8)
    g = Scene(leafy).render()
    for label in (TWIG, NEEDLE, SKY):
        assert (g.labels == label).sum() > 50, label
    assert leafy.has_foliage and leafy.rect_error_px == 0.3 and leafy.right_gain != 1.0


def test_vary_leafy_draws_the_plain_keys_first():
    from uav_depth.sim.scene import vary

    base = _small()
    plain = vary(base, np.random.default_rng(8))
    leafy = vary(base, np.random.default_rng(8), leafy=True)
    assert leafy.has_foliage and not plain.has_foliage
    for key in ("branch_distance_m", "branch_radius_m", "n_branches", "brightness", "seed", "texture_scale"):
        assert getattr(leafy, key) == getattr(plain, key), key


def test_needles_are_in_the_truth_depth_at_their_surface():
    """Every needle pixel's depth puts the point on that needle's surface (1 mm thick): exact truth."""
    from uav_depth.sim.scene import NEEDLE

    cfg = _small(fascicles=30, twigs=2)
    scene = Scene(cfg)
    f = scene.render()
    ys, xs = np.nonzero(f.labels == NEEDLE)
    assert ys.size > 100
    cx, cy = cfg.calibration.principal_point
    z = f.depth[ys, xs].astype(np.float64)
    pts = np.stack([(xs - cx) / cfg.focal_px * z, (ys - cy) / cfg.focal_px * z, z], axis=1)
    for obj in np.unique(f.objects[ys, xs]):
        cyl = scene.cylinders[obj - 1]
        assert cyl.kind == NEEDLE and cyl.thickness_m == pytest.approx(0.001)
        p = pts[f.objects[ys, xs] == obj] - cyl.p0
        radial = p - (p @ cyl.axis)[:, None] * cyl.axis
        assert np.allclose(np.linalg.norm(radial, axis=1), cyl.radius, atol=2e-5)
    assert np.allclose(f.disparity[ys, xs] * f.depth[ys, xs], cfg.focal_px * cfg.baseline_m, rtol=1e-5)


def test_batched_needles_hit_the_same_pixels_as_needles_cast_one_by_one(monkeypatch):
    cfg = _small(fascicles=30, twigs=2)
    fast = Scene(cfg).render()

    def one_by_one(needles, o, rot, dirs, focal_px, principal_point, depth, labels, intensity, objects, light):
        return list(range(len(needles)))           # "cast each alone": the scene's one-cylinder path

    monkeypatch.setattr(scene_module, "cast_needles", one_by_one)
    slow = Scene(cfg).render()
    same = fast.objects == slow.objects
    assert (fast.labels == 4).sum() > 100
    assert same.mean() > 0.9995                          # float32 vs float64 at grazing edges only
    both = same & np.isfinite(fast.depth)
    # the batch computes in float64; the one-by-one float32 path loses ~1e-4 to cancellation on a 0.5 mm radius
    assert np.allclose(fast.depth[both], slow.depth[both], rtol=1e-3)


def test_significant_object_is_a_twig_not_a_needle():
    """Needles (1 mm) are never the truth; a 3-10 mm twig in front is; the rule is metric."""
    from uav_depth.sim.scene import NEEDLE, TWIG
    from uav_depth.sim.truth import SIGNIFICANT_AREA_M2, SIGNIFICANT_WIDTH_M, is_significant

    assert not is_significant(0.001, 1.0) and not is_significant(0.01, 1e-5) and is_significant(0.003, 2e-4)
    only_needles = _small(fascicles=60)
    scene = Scene(only_needles)
    f = scene.render()
    roi = only_needles.center_roi
    t = f.truth(roi)
    assert (f.labels[roi[1]:roi[3], roi[0]:roi[2]] == NEEDLE).sum() > 50
    assert t.nearest_any_m < t.significant_m - 0.05                    # needles in front, not counted
    assert scene.cylinders[t.object_index - 1].kind != NEEDLE
    assert t.significant_m == pytest.approx(f.nearest_branch_distance(roi), rel=1e-6)
    with_twigs = _small(twigs=5, fascicles=20)
    scene = Scene(with_twigs)
    t = scene.render().truth(roi)
    hit = scene.cylinders[t.object_index - 1]
    assert hit.kind == TWIG and hit.thickness_m >= SIGNIFICANT_WIDTH_M and t.area_m2 >= SIGNIFICANT_AREA_M2
    assert t.significant_m < 0.8 * 0.98


def test_sky_is_bright_at_infinity_and_covers_its_share():
    from uav_depth.sim.scene import SKY

    f = Scene(_small(sky_fraction=0.3, n_branches=0)).render()
    sky = f.labels == SKY
    far = sky | (f.labels == 0)
    assert 0.15 < sky.sum() / far.sum() < 0.45
    assert np.all(np.isinf(f.depth[sky])) and np.all(f.disparity[sky] == 0) and np.all(f.objects[sky] == -1)
    assert f.left[sky].min() >= 250 and np.median(f.left[f.labels == 0]) < 200


def test_hard_shadows_darken_by_the_set_strength_and_leave_geometry():
    cfg = _small(twigs=5, fascicles=20, brightness=0.0)
    lit = Scene(cfg).render()
    dark = Scene(replace(cfg, shadow_strength=0.6)).render()
    assert np.array_equal(lit.depth, dark.depth)
    changed = dark.left.astype(int) < lit.left.astype(int) - 2
    assert changed.sum() > 200
    ratio = dark.left[changed] / np.maximum(lit.left[changed], 1)
    assert np.median(ratio) == pytest.approx(0.4, abs=0.03)


def test_right_eye_gain_offset_and_blur_change_the_right_view_only():
    cfg = _small(brightness=-20.0)
    a = Scene(cfg).render()
    b = Scene(replace(cfg, right_gain=1.2, right_offset=-5.0)).render()
    assert np.array_equal(a.left, b.left)
    expect = np.clip(a.right.astype(float) * 1.2 - 5.0, 0, 255)
    assert np.abs(b.right - expect).max() <= 1.5
    c = Scene(replace(cfg, right_blur_sigma=1.0)).render()
    lap = lambda img: cv2.Laplacian(img.astype(np.float32), cv2.CV_32F).var()  # noqa: E731
    assert np.array_equal(a.left, c.left) and lap(c.right) < 0.7 * lap(a.right)


@pytest.mark.parametrize("shift", [1.0, 0.4, -0.3])
def test_rectification_error_shifts_right_rows_by_the_set_amount(shift):
    cfg = _small()
    a = Scene(cfg).render()
    b = Scene(replace(cfg, rect_error_px=shift)).render()
    assert np.array_equal(a.left, b.left) and np.array_equal(a.disparity, b.disparity)
    if shift == 1.0:    # whole pixel: row y of b is row y - 1 of a
        assert np.abs(b.right[1:].astype(int) - a.right[:-1].astype(int)).max() <= 1
    (_, dy), _ = cv2.phaseCorrelate(a.right.astype(np.float64), b.right.astype(np.float64))
    assert dy == pytest.approx(shift, abs=0.08)


@pytest.mark.parametrize("key,value,msg", [("rect_error_px", 9.0, "between -5 and 5"),
                                           ("sky_fraction", 1.0, "between 0 and 0.9"),
                                           ("fascicles", -1, "between 0 and 400"),
                                           ("twigs", 1.5, "must be an integer")])
def test_bad_foliage_and_camera_keys(key, value, msg):
    with pytest.raises(ConfigError, match=msg):
        SceneConfig.from_dict({key: value})


def test_culled_leafy_render_equals_full_frame_cast(monkeypatch):
    """Twigs, small branches, sky and shadows go through the same culling: it must drop no hit."""
    cfg = SceneConfig.leafy(seed=6, width=320, height=180, focal_px=175.0, branch_distance_m=0.7, fascicles=0)
    fast = Scene(cfg).render(rng=np.random.default_rng(1))
    monkeypatch.setattr(Scene, "CULL", False)
    full = Scene(cfg).render(rng=np.random.default_rng(1))
    assert (fast.labels == 3).sum() > 50
    for name in ("left", "right", "labels", "objects", "depth"):
        assert np.array_equal(getattr(fast, name), getattr(full, name)), name


@pytest.mark.parametrize("pose", [Pose(), _turned(8.0, [0.05, 0.02, 0.3])], ids=["identity", "turned"])
def test_one_batch_of_cylinders_is_each_cast_alone_in_turn(monkeypatch, pose):
    """The batched cast (sim/cylinders.py) keeps the one-by-one rule: scene order, a later cylinder takes a
    pixel only when strictly nearer. A twin of the target branch at the same place must lose every tie."""
    from uav_depth.sim.cylinders import CylinderGroup

    cfg = SceneConfig.leafy(seed=4, width=320, height=180, focal_px=175.0, branch_distance_m=0.8, fascicles=0)
    scene = Scene(cfg)
    members = [(i + 1, c) for i, c in enumerate(scene.cylinders)]
    twin = (len(members) + 1, scene.cylinders[1])            # the target branch again, object index past the end
    scene._solid = CylinderGroup.of(members + [twin])
    batched = scene.render(pose, np.random.default_rng(2))

    def in_turn(self, group, *args):
        for member in zip(group.objects, group.cylinders):
            cast(self, CylinderGroup.of([member]), *args)

    cast = Scene._cast
    monkeypatch.setattr(Scene, "_cast", in_turn)
    alone = scene.render(pose, np.random.default_rng(2))
    assert (batched.objects == 2).sum() > 100 and not (batched.objects == twin[0]).any()
    for name in ("left", "right", "labels", "objects", "depth"):
        assert np.array_equal(getattr(batched, name), getattr(alone, name)), name
