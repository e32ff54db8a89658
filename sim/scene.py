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

Optional, all off by default (the default scene is pixel for pixel what it was):
foliage in front of the target (twigs, needle fascicles, small branches:
:mod:`uav_depth.sim.foliage`), bright sky seen through gaps in the canopy, hard
shadows from the sun (:class:`uav_depth.sim.geometry.ShadowMap`), and the camera
differences of real rigs (:mod:`uav_depth.sim.camera`, and ``rect_error_px``).
:meth:`SceneConfig.leafy` is the preset with all of them; ``vary(..., leafy=True)``
draws them at random. :meth:`StereoFrame.truth` gives the nearest *significant*
object (:mod:`uav_depth.sim.truth`). docs/scenes.md says what and why.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import cv2
import numpy as np

from uav_depth.sim.camera import finish
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


class Scene:
    """A built scene: geometry and textures fixed by the config's seed; render any pose."""

    def __init__(self, config: SceneConfig):
        self.config = config
        rng = np.random.default_rng(config.seed)
        self.textures = [_texture(rng, _TEX_SIZE, True), _texture(rng, _TEX_SIZE, True),
                         _texture(rng, _TEX_SIZE, False)]
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
        # fractional part, so no image row repeats it: a tile laid square repeated
        # every 3 m, inside SGBM's search range for far backgrounds, and SGBM
        # matched the wrong repeat with full confidence.
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

        needles = []
        for i, cyl in enumerate(self.cylinders):
            if cyl.kind == NEEDLE:
                needles.append((i + 1, cyl))
            else:
                self._cast_cylinder(cyl, i + 1, origin, rot, dx, dy, dz, depth, labels, intensity, objects, view)
        if needles:
            alone = cast_needles(needles, origin, rot, (dx, dy, dz), c.focal_px, shifted(self.calibration.principal_point, view),
                                 depth, labels, intensity, objects, _LIGHT)
            for n in alone:
                self._cast_cylinder(needles[n][1], needles[n][0], origin, rot, dx, dy, dz, depth, labels,
                                    intensity, objects, view)
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

    def _candidates(self, cyl: Cylinder, o: np.ndarray, rot: np.ndarray, view: View) -> np.ndarray | None:
        """Flat indices of the pixels whose rays may hit ``cyl``; None means every pixel.

        Conservative culling (why the renderer is fast): the axis is cut into pieces
        about one radius long; each piece lies inside a sphere, and the sphere inside
        an axis-aligned cube in camera coordinates. x/z and y/z are monotonic in each
        coordinate for z > 0, so the cube's corners bound the piece's projection.
        Boxes are widened by two pixels against float32 rounding in the hit test. A
        piece that reaches the camera plane (z <= 0 somewhere) could project
        anywhere: then every pixel is a candidate. The per-pixel arithmetic is the
        same for candidates as before, so the image does not change. Indices: ``view``'s.
        """
        c = self.config
        h, w = view[3] - view[1], view[2] - view[0]
        centres, _, rho = cyl.pieces()
        cam = (centres - o[None, :]) @ rot                     # rows: rot.T @ (C - o)
        cx, cy = shifted(self.calibration.principal_point, view)
        zlo, zhi = cam[:, 2] - rho, cam[:, 2] + rho
        front = zhi > 0                                         # pieces wholly behind cannot be hit (t > 0)
        if np.any(front & (zlo <= 1e-6)):
            return None
        cam, zlo, zhi = cam[front], zlo[front], zhi[front]
        if not len(cam):
            return np.zeros(0, np.intp)
        margin = 2
        bounds = []
        for axis, centre, size in ((0, cx, w), (1, cy, h)):
            corners = np.stack([(cam[:, axis] + sx * rho) / z for sx in (-1.0, 1.0) for z in (zlo, zhi)])
            lo = np.floor(centre + c.focal_px * corners.min(axis=0)).astype(np.int64) - margin
            hi = np.ceil(centre + c.focal_px * corners.max(axis=0)).astype(np.int64) + margin
            bounds.append((np.clip(lo, 0, size), np.clip(hi + 1, 0, size)))
        (j0, j1), (i0, i1) = bounds
        keep = (i0 < i1) & (j0 < j1)
        if not keep.any():
            return np.zeros(0, np.intp)
        i0, i1, j0, j1 = i0[keep], i1[keep], j0[keep], j1[keep]
        # The union of the boxes, marked in their bounding box only (thin cylinders have many small ones).
        bi, bj = int(i0.min()), int(j0.min())
        mask = np.zeros((int(i1.max()) - bi, int(j1.max()) - bj), bool)
        for a, b, cc, d in zip(i0 - bi, i1 - bi, j0 - bj, j1 - bj):
            mask[a:b, cc:d] = True
        rows, cols = np.nonzero(mask)
        return (rows + bi) * w + (cols + bj)

    def _cast_cylinder(self, cyl: Cylinder, obj: int, o: np.ndarray, rot: np.ndarray, dx, dy, dz, depth, labels,
                       intensity, objects, view: View) -> None:
        idx = self._candidates(cyl, o, rot, view)
        if idx is None:
            idx = np.arange(depth.size)
        if not idx.size:
            return
        # Work on the candidate pixels only, as flat vectors: elementwise float32
        # arithmetic gives the same value per pixel whatever the array's shape.
        dxc, dyc, dzc = dx.ravel()[idx], dy.ravel()[idx], dz.ravel()[idx]
        a = cyl.axis.astype(np.float64)
        wv = o - cyl.p0
        wa = float(wv @ a)
        wp = wv - wa * a                                       # w perpendicular to the axis
        da = dxc * np.float32(a[0]) + dyc * np.float32(a[1]) + dzc * np.float32(a[2])
        dpx, dpy, dpz = dxc - da * np.float32(a[0]), dyc - da * np.float32(a[1]), dzc - da * np.float32(a[2])
        A = dpx * dpx + dpy * dpy + dpz * dpz
        B = 2.0 * (dpx * np.float32(wp[0]) + dpy * np.float32(wp[1]) + dpz * np.float32(wp[2]))
        C = np.float32(wp @ wp - cyl.radius ** 2)
        disc = B * B - 4.0 * A * C
        ok = disc >= 0
        if not ok.any():
            return
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-B - np.sqrt(np.where(ok, disc, 0))) / (2.0 * A)
        s = wa + t * da
        ok &= (t > 0) & (s >= 0) & (s <= cyl.length) & (t < depth.ravel()[idx])
        if not ok.any():
            return
        sel = np.flatnonzero(ok)
        flat = idx[sel]
        tt = t[sel]
        hx = o[0] + tt * dxc[sel] - cyl.p0[0]
        hy = o[1] + tt * dyc[sel] - cyl.p0[1]
        hz = o[2] + tt * dzc[sel] - cyl.p0[2]
        ss = s[sel]
        nx, ny, nz = hx - ss * a[0], hy - ss * a[1], hz - ss * a[2]     # radial vector, length r
        e1 = np.cross(a, [0.0, 0.0, 1.0])
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(a, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        ang = np.arctan2(nx * e2[0] + ny * e2[1] + nz * e2[2], nx * e1[0] + ny * e1[1] + nz * e1[2])
        scale = _TEX_SIZE / _TEX_M[True] * self.config.texture_scale
        # Bark grain spirals at an irrational angle, so the tile does not repeat along the
        # branch: laid straight it came back every 0.25 m, inside SGBM's search range for a
        # branch at 1.7 m, and SGBM matched the wrong repeat (a false branch at 0.32 m).
        au, av = ang * cyl.radius, ss
        tu = ((au * _BARK_COS - av * _BARK_SIN) * scale).astype(np.float32)
        tv = ((au * _BARK_SIN + av * _BARK_COS) * scale).astype(np.float32)
        tex = self._sample_points(cyl.texture, tu, tv)
        shade = 0.35 + 0.65 * np.clip((nx * _LIGHT[0] + ny * _LIGHT[1] + nz * _LIGHT[2]) / cyl.radius, 0, 1)
        depth.ravel()[flat] = tt
        labels.ravel()[flat] = cyl.kind
        objects.ravel()[flat] = obj
        intensity.ravel()[flat] = (cyl.albedo * (0.45 + 0.55 * tex) * shade).astype(np.float32)

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
        # The branch mask helps branch-aware fitness later.
        np.save(writer.session.frames_dir / f"{i:06d}_branch.npy", frame.branch_mask)
        if progress is not None:
            progress(i + 1, frames)
    return writer.session
