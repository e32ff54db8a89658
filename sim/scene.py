"""Synthetic forestry scenes: rectified stereo pairs with exact disparity and branch distance.

The test bed of the project (tuning, daemon, SITL, benchmarks). A scene is a
vertical trunk with several branches (finite cylinders) in front of a textured
far background plane. Textures are attached to the surfaces (arc length and
axial position on a cylinder, metric X/Y on the plane), so both views see the
same bark at the same place and stereo matching behaves as on real images.

Frames: camera x right, y down, z forward (OpenCV). The world frame is the left
camera's frame at the identity pose. A pose moves the stereo rig in the world
(``R`` columns are the camera axes in world coordinates, ``t`` its centre), which
is how SITL flies the virtual camera toward the tree.

Both views are ray-cast analytically, so the left disparity d = f*B/Z is exact
and the distance to the nearest branch surface is known to pixel sampling.

Optional, all off by default (so figures measured on the default scene stay reproducible):
foliage in front of the target (twigs, needle fascicles, small branches:
:mod:`uav_depth.sim.foliage`), bright sky seen through gaps in the canopy, hard
shadows from the sun (:class:`uav_depth.sim.geometry.ShadowMap`), and the camera
differences of real rigs (:mod:`uav_depth.sim.camera`, and ``rect_error_px``).
:meth:`SceneConfig.leafy` is the preset with all of them; ``vary(..., leafy=True)``
draws them at random. :meth:`StereoFrame.truth` gives the nearest *significant*
object (:mod:`uav_depth.sim.truth`). docs/scenes.md says what and why.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import replace

import cv2
import numpy as np

from uav_depth.sim.camera import finish
from uav_depth.sim.cylinders import CylinderGroup, cast_cylinders
from uav_depth.sim.foliage import foliage
from uav_depth.sim.geometry import BACKGROUND, BRANCH, NEEDLE, SKY, TRUNK, TWIG, Cylinder, ShadowMap
from uav_depth.sim.texture import (BARK_COS as _BARK_COS, BARK_SIN as _BARK_SIN, BG_COS as _BG_COS,
                                   BG_SIN as _BG_SIN, TEX_M as _TEX_M,
                                   TEX_SIZE as _TEX_SIZE, periodic_noise as _periodic_noise, texture as _texture,
                                   wrap as _wrap)
from uav_depth.sim.frame import Pose, StereoFrame, View, nearest_distance, paste, shifted, window_views
from uav_depth.sim.needles import cast_needles
from uav_depth.sim.scene_config import SceneConfig, background_period_px, vary
from uav_depth.sim.truth import Truth

__all__ = ["BACKGROUND", "BRANCH", "NEEDLE", "SKY", "TRUNK", "TWIG", "Cylinder", "Pose", "Scene", "SceneConfig",
           "StereoFrame", "Truth", "background_period_px", "nearest_distance", "render_pair", "time_render",
           "vary", "write_session"]

_LIGHT = np.array([-0.4, -0.6, 0.7]) / np.linalg.norm([-0.4, -0.6, 0.7])   # toward the light (shading)


@functools.lru_cache(maxsize=16)
def _seeded_textures(seed: int) -> tuple[tuple[np.ndarray, ...], dict]:
    """The surface textures a scene of ``seed`` draws first from its generator, and the generator's state after
    them. Scenes of one seed at many branch distances (a near sweep, tune's safety sweep and search guide) share
    them, and they are about 40 % of a 640x360 render. Read-only: every scene of the seed holds the same arrays."""
    rng = np.random.default_rng(seed)
    textures = (_texture(rng, _TEX_SIZE, True), _texture(rng, _TEX_SIZE, True), _texture(rng, _TEX_SIZE, False))
    for t in textures:
        t.flags.writeable = False
    return textures, rng.bit_generator.state


class Scene:
    """A built scene: geometry and textures fixed by the config's seed; render any pose."""

    def __init__(self, config: SceneConfig):
        self.config = config
        textures, state = _seeded_textures(config.seed)
        rng = np.random.default_rng(config.seed)
        rng.bit_generator.state = state           # as if it had drawn the textures itself
        self.textures = list(textures)
        layout = self._layout(rng)
        self.cylinders = layout + foliage(config)
        self.calibration = config.calibration
        # Object index 0 is the background plane, i + 1 cylinder i.
        self.thickness_m = np.array([math.inf] + [cyl.thickness_m for cyl in self.cylinders])
        self._sky_cut: float | None = None
        if config.sky_fraction > 0:
            # Canopy gaps: a coarse mask texture of their own stream, cut at the quantile that
            # leaves sky_fraction of the far plane open.
            gaps = _periodic_noise(np.random.default_rng([config.seed, 12]), _TEX_SIZE, 6.0, 6.0).astype(np.float32)
            self.textures.append(gaps)
            self._sky_cut = float(np.quantile(gaps[::4, ::4], 1.0 - config.sky_fraction))
        self._shadows: ShadowMap | None = None
        if config.shadow_strength > 0:
            # The foliage and the target cast them when there is foliage, else every branch;
            # the trunk (4 m tall) would only stretch the map.
            occluders = [(i + 1, cyl) for i, cyl in enumerate(self.cylinders) if cyl.kind != TRUNK
                         and (not config.has_foliage or i == 1 or i >= len(layout))]
            self._shadows = ShadowMap(occluders, [o for o in occluders if o[0] > len(layout)] or occluders)
        self._dirs_cache: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # Everything but the needles is cast in one batch (sim/cylinders.py), in scene order.
        self._solid = CylinderGroup.of([(i + 1, cyl) for i, cyl in enumerate(self.cylinders) if cyl.kind != NEEDLE])

    def _layout(self, rng: np.random.Generator) -> list[Cylinder]:
        c = self.config
        d, r = c.branch_distance_m, c.branch_radius_m
        zc = d + r                          # target branch axis depth: nearest surface at d
        side = rng.choice([-1.0, 1.0])
        half_w = (c.width / 2.0) / c.focal_px * (zc + c.trunk_offset_m)
        trunk_x = side * min(max(0.35 * half_w, 0.15), 1.5)
        trunk_z = zc + c.trunk_offset_m
        trunk_r = float(rng.uniform(0.08, 0.15))
        tall = 4.0 * (1.0 + trunk_z)
        cyl = [Cylinder(np.array([trunk_x, -tall / 2, trunk_z]), np.array([0.0, 1.0, 0.0]), tall, trunk_r,
                        TRUNK, 0, float(rng.uniform(0.45, 0.6)))]
        angle = c.branch_angle_deg if c.branch_angle_deg is not None else float(rng.uniform(-30, 30))
        a = math.radians(angle)
        axis = np.array([-side * math.cos(a), math.sin(a), 0.0])
        # The target branch lies in the plane z = zc and passes through the optical axis.
        span = abs(trunk_x) + 2.0 * half_w
        start = np.array([0.0, 0.0, zc]) - axis * abs(trunk_x) / max(abs(axis[0]), 1e-3)
        cyl.append(Cylinder(start, axis, span, r, BRANCH, 1, float(rng.uniform(0.55, 0.75))))
        for _ in range(c.n_branches):
            z = zc + float(rng.uniform(0.15, 0.9)) * c.trunk_offset_m / 0.35
            y0 = float(rng.uniform(-0.8, 0.8)) * (c.height / 2.0) / c.focal_px * z
            if abs(y0) < 3 * r + 0.03 * z:          # keep the image centre for the target branch
                y0 += math.copysign(4 * r + 0.05 * z, y0 or 1.0)
            ang = math.radians(float(rng.uniform(-40, 40)))
            ax = np.array([-side * math.cos(ang), math.sin(ang), float(rng.uniform(-0.25, 0.25))])
            ax /= np.linalg.norm(ax)
            length = float(rng.uniform(0.6, 1.2)) * span
            rad = float(rng.uniform(0.4, 1.2)) * r
            cyl.append(Cylinder(np.array([trunk_x, y0, z]), ax, length, rad, BRANCH, 1,
                                float(rng.uniform(0.5, 0.8))))
        return cyl

    # -- rendering ---------------------------------------------------------------------------

    def _rays(self, row_shift_px: float, view: View) -> tuple[np.ndarray, np.ndarray]:
        c = self.config
        cx, cy = self.calibration.principal_point
        u = (np.arange(view[0], view[2], dtype=np.float32) - cx) / np.float32(c.focal_px)
        if row_shift_px == 0.0:
            v = (np.arange(view[1], view[3], dtype=np.float32) - cy) / np.float32(c.focal_px)
        else:   # row y sees what row y - shift of a perfect rig sees
            v = ((np.arange(view[1], view[3], dtype=np.float64) - row_shift_px - cy) / c.focal_px).astype(np.float32)
        return u, v

    def _directions(self, rot: np.ndarray, row_shift_px: float, view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World ray directions rot @ (u, v, 1) over ``view``, each (H, W) float32, read-only.

        Both views share them (unless the right one has a rectification error), and
        the last rotation's are kept: a rig that flies without turning (SITL's
        approach, benchmarks) computes them once.
        """
        key = (np.asarray(rot, dtype=np.float64).tobytes() + np.float64(row_shift_px).tobytes()
               + np.asarray(view, np.int64).tobytes())
        if key in self._dirs_cache:
            return self._dirs_cache[key]
        h, w = view[3] - view[1], view[2] - view[0]
        u, v = self._rays(row_shift_px, view)
        dx = rot[0, 0] * u[None, :] + rot[0, 1] * v[:, None] + np.float32(rot[0, 2])
        dy = rot[1, 0] * u[None, :] + rot[1, 1] * v[:, None] + np.float32(rot[1, 2])
        dz = rot[2, 0] * u[None, :] + rot[2, 1] * v[:, None] + np.float32(rot[2, 2])
        dirs = tuple(np.broadcast_to(a, (h, w)).astype(np.float32) for a in (dx, dy, dz))
        for a in dirs:
            a.flags.writeable = False
        if len(self._dirs_cache) >= 2:
            self._dirs_cache.clear()
        self._dirs_cache[key] = dirs  # type: ignore[assignment]
        return dirs  # type: ignore[return-value]

    def _render_view(self, origin: np.ndarray, rot: np.ndarray, dirs: tuple[np.ndarray, np.ndarray, np.ndarray],
                     view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Ray-cast one view over ``view`` (the part of the image). Returns (intensity float32 0..1-ish,
        depth m, labels, objects)."""
        c = self.config
        h, w = view[3] - view[1], view[2] - view[0]
        # Ray direction in world = rot @ (u, v, 1); t along it is depth along the optical axis.
        dx, dy, dz = dirs
        labels = np.zeros((h, w), np.uint8)

        # Background plane z = Zbg in the world.
        zbg = c.background_distance_m
        with np.errstate(divide="ignore", invalid="ignore"):
            tb = (np.float32(zbg) - np.float32(origin[2])) / dz
        hit = np.isfinite(tb) & (tb > 0)
        depth = np.where(hit, tb, np.float32(np.inf))
        objects = np.where(hit, np.int16(0), np.int16(-1))
        px = origin[0] + tb * dx
        py = origin[1] + tb * dy
        # The foliage tile is laid at an angle whose tangent is the golden ratio's
        # fractional part, so no image row repeats it: a tile laid square would repeat
        # every 3 m, inside SGBM's search range for far backgrounds, and SGBM would
        # match the wrong repeat with full confidence.
        scale = _TEX_SIZE / _TEX_M[False] * c.texture_scale
        ru, rv = (px * _BG_COS - py * _BG_SIN) * scale, (px * _BG_SIN + py * _BG_COS) * scale
        tex = self._sample(2, ru, rv)
        intensity = np.where(hit, 0.55 * tex + 0.25, np.float32(0.0))
        if self._sky_cut is not None:
            # Gaps 4x coarser than the canopy's texture; through them the sky, at infinity.
            sky = hit & (self._sample(3, ru * 0.25, rv * 0.25) > self._sky_cut)
            depth[sky] = np.inf
            objects[sky] = -1
            labels[sky] = SKY
            intensity[sky] = np.float32(c.sky_level)

        pp = shifted(self.calibration.principal_point, view)
        self._cast(self._solid, origin, rot, dirs, pp, depth, labels, intensity, objects)
        needles = [(i + 1, cyl) for i, cyl in enumerate(self.cylinders) if cyl.kind == NEEDLE]
        if needles:
            alone = cast_needles(needles, origin, rot, (dx, dy, dz), c.focal_px, pp, depth, labels, intensity,
                                 objects, _LIGHT)
            for n in alone:
                self._cast(CylinderGroup.of([needles[n]]), origin, rot, dirs, pp, depth, labels, intensity, objects)
        if self._shadows is not None:
            self._shade(origin, dx, dy, dz, depth, objects, intensity)
        return intensity, depth, labels, objects

    def _shade(self, o: np.ndarray, dx, dy, dz, depth, objects, intensity) -> None:
        """Darken what lies in another object's sun shadow (hard shadows: a sharp edge)."""
        flat = np.flatnonzero(objects.ravel() >= 0)
        t = depth.ravel()[flat]
        x = o[0] + t * dx.ravel()[flat]
        y = o[1] + t * dy.ravel()[flat]
        z = o[2] + t * dz.ravel()[flat]
        dark = flat[self._shadows.shadowed(x, y, z, objects.ravel()[flat])]
        intensity.ravel()[dark] *= np.float32(1.0 - self.config.shadow_strength)

    def _sample(self, tex_id: int, tu: np.ndarray, tv: np.ndarray) -> np.ndarray:
        mx = np.ascontiguousarray(_wrap(tu), dtype=np.float32)
        my = np.ascontiguousarray(_wrap(tv), dtype=np.float32)
        return cv2.remap(self.textures[tex_id], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    def _sample_points(self, tex_id: int, tu: np.ndarray, tv: np.ndarray) -> np.ndarray:
        # cv2.remap wants 2-D maps under 32767 a side: fold the point list into rows.
        n = tu.size
        cols = 1024
        rows = -(-n // cols)
        pad = rows * cols - n
        fold = lambda a: np.pad(a, (0, pad)).reshape(rows, cols)  # noqa: E731
        return self._sample(tex_id, fold(tu), fold(tv)).ravel()[:n]

    #: False casts every ray at every cylinder (tests: culling must drop no hit).
    CULL = True

    def _cast(self, group: CylinderGroup, origin, rot, dirs, pp, depth, labels, intensity, objects) -> None:
        cast_cylinders(group, origin, rot, dirs, self.config.focal_px, pp, depth, labels, intensity, objects, _LIGHT,
                       _TEX_SIZE / _TEX_M[True] * self.config.texture_scale, _BARK_COS, _BARK_SIN,
                       self._sample_points, self.CULL)

    def render(self, pose: Pose | None = None, rng: np.random.Generator | None = None, window: View | None = None):
        """Render both views at ``pose`` (default identity). ``rng`` draws the sensor noise. ``window``:
        ray-cast only that part (:func:`~uav_depth.sim.frame.window_views`; the rest is blank)."""
        pose = pose or Pose()
        rng = rng if rng is not None else np.random.default_rng(self.config.seed)
        c = self.config
        rot = np.asarray(pose.rotation, dtype=np.float64)
        o_left = np.asarray(pose.position, dtype=np.float64)
        o_right = o_left + rot @ np.array([c.baseline_m, 0.0, 0.0])
        # The blur reaches this far around the window (OpenCV's float kernel radius: 4 sigma).
        inner, view = window_views(c.width, c.height, window, 4.0 * math.hypot(c.blur_sigma, c.right_blur_sigma))
        dirs = self._directions(rot, 0.0, view)
        il, depth, labels, objects = self._render_view(o_left, rot, dirs, view)
        dirs_r = dirs if c.rect_error_px == 0 else self._directions(rot, c.rect_error_px, view)
        ir, _, labels_r, _ = self._render_view(o_right, rot, dirs_r, view)
        left = finish(c, il, labels, rng)
        right = finish(c, ir, labels_r, rng, right=True)
        if window is not None:
            left, right, depth, labels, objects = (paste(a, view, inner, (c.height, c.width), fill) for a, fill in
                                                   ((left, 0), (right, 0), (depth, np.inf), (labels, SKY), (objects, -1)))
        with np.errstate(divide="ignore"):
            disp = (c.focal_px * c.baseline_m / depth).astype(np.float32)
        return StereoFrame(left, right, disp, depth, labels, objects, self.thickness_m, c.focal_px)



def render_pair(config: SceneConfig, pose: Pose | None = None, frame_index: int = 0) -> StereoFrame:
    """Build ``config``'s scene and render one frame; the noise is seeded by (seed, frame_index)."""
    scene = Scene(config)
    return scene.render(pose, np.random.default_rng([config.seed, frame_index]))


def time_render(config: SceneConfig, repeats: int = 3) -> float:
    """Median seconds to render one pair of ``config`` (scene built once)."""
    scene = Scene(config)
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        scene.render(rng=np.random.default_rng(i))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def write_session(outdir, frames: int, seed: int, base: SceneConfig | None = None, vary_scenes: bool = True,
                  fixed_distance: float | None = None, progress=None):
    """Write a synthetic session in the log layout: pairs, exact reference disparity,
    calibration, and per-frame truth (nearest branch distance in the centre ROI).

    Frame ``i`` uses a scene drawn from ``numpy.random.default_rng([seed, i])``, so
    a frame does not depend on how many frames are written. ``progress(done, total)``
    is called after each frame when given.
    """
    from uav_depth.core.session import SessionWriter

    base = base or SceneConfig()
    writer = SessionWriter(outdir, base.calibration)
    for i in range(frames):
        rng = np.random.default_rng([seed, i])
        fixed = {} if fixed_distance is None else {"branch_distance_m": fixed_distance}
        cfg = (vary(base, rng, **fixed) if vary_scenes
               else replace(base, seed=int(rng.integers(0, 2**31 - 1)), **fixed))
        frame = Scene(cfg).render(rng=rng)
        roi = cfg.center_roi
        meta = {"branch_distance_m": frame.nearest_branch_distance(roi), "roi": list(roi), "scene": cfg.to_dict()}
        writer.write(i, frame.left, frame.right, reference=frame.disparity, meta=meta,
                     reference_source={"kind": "synthetic", "exact": True,
                                       "note": "ray-cast ground truth from uav_depth.sim.scene"})
        # Which pixels are branch surface, beside the frame (the tuner loads it as FrameData.branch_mask).
        np.save(writer.session.frames_dir / f"{i:06d}_branch.npy", frame.branch_mask)
        if progress is not None:
            progress(i + 1, frames)
    return writer.session
