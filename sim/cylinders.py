"""Ray casting of the scene's solid cylinders (trunk, branches, twigs) into one view, all at once.

Cast one by one, each cylinder costs about sixty numpy calls per view, most of them on a few
thousand pixels: the calls, not the arithmetic, would be most of a SITL frame's render. Here
the culling, the hit test and the surface (texture, shading) run once over every (cylinder,
candidate pixel) pair of a view, with each cylinder's constants spread over its pairs.

The result is bit for bit what casting each cylinder alone, in turn, gives (tests/sim/test_scene.py
compares them):

- a pair's arithmetic does not depend on the other pairs: the same IEEE operations on the same
  dtypes (each cylinder's float32 constants spread over its pairs, float64 where float64);
- cylinders are cast in scene order and a later one takes a pixel only when strictly nearer,
  so the nearest wins and, on a tie, the first (the depth test is the only step done per cylinder);
- the surface is computed for the pixels each cylinder finally owns; texture samples are
  independent of each other, so sampling them together changes none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from uav_depth.sim.geometry import Cylinder

#: ``sample(texture index, u, v)``: the texture's values at points (u, v: (n,) float32 texture px).
Sampler = Callable[[int, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CylinderGroup:
    """Cylinders to cast together, with what the renderer derives from each alone (once per scene)."""

    objects: np.ndarray       # (n,) int16 object index of each
    cylinders: tuple
    p0: np.ndarray            # (n, 3) float64
    axis: np.ndarray          # (n, 3) float64
    axis32: np.ndarray        # (n, 3) float32
    e1: np.ndarray            # (n, 3) the texture frame across the axis
    e2: np.ndarray
    radius: np.ndarray        # (n,) float64
    length32: np.ndarray      # (n,) float32
    albedo32: np.ndarray      # (n,) float32
    kind: np.ndarray          # (n,) uint8
    texture: np.ndarray       # (n,) texture index
    centres: np.ndarray       # (P, 3) the culling pieces' centres (Cylinder.pieces), all cylinders
    rho: np.ndarray           # (P,) their spheres' radii
    owner: np.ndarray         # (P,) which cylinder each piece belongs to

    @staticmethod
    def of(members: Sequence[tuple[int, Cylinder]]) -> "CylinderGroup":
        cyls = tuple(c for _, c in members)
        axis = np.array([c.axis for c in cyls], np.float64).reshape(-1, 3)
        e1s, e2s, centres, rho, owner = [], [], [], [], []
        for k, (a, cyl) in enumerate(zip(axis, cyls)):
            e1 = np.cross(a, [0.0, 0.0, 1.0])
            if np.linalg.norm(e1) < 1e-6:
                e1 = np.cross(a, [1.0, 0.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e1s.append(e1)
            e2s.append(np.cross(a, e1))
            c, _, r = cyl.pieces()
            centres.append(c)
            rho.append(np.full(len(c), r))
            owner.append(np.full(len(c), k, np.int64))
        cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)  # noqa: E731
        return CylinderGroup(
            np.array([o for o, _ in members], np.int16), cyls,
            np.array([c.p0 for c in cyls], np.float64).reshape(-1, 3), axis, axis.astype(np.float32),
            np.array(e1s).reshape(-1, 3), np.array(e2s).reshape(-1, 3), np.array([c.radius for c in cyls], np.float64),
            np.array([c.length for c in cyls], np.float32), np.array([c.albedo for c in cyls], np.float32),
            np.array([c.kind for c in cyls], np.uint8), np.array([c.texture for c in cyls], np.int64),
            cat(centres, (0, 3)), cat(rho, (0,)), cat(owner, (0,)).astype(np.int64))

    def __len__(self) -> int:
        return len(self.cylinders)


def candidates(group: CylinderGroup, o: np.ndarray, rot: np.ndarray, focal_px: float,
               principal_point: tuple[float, float], h: int, w: int, cull: bool = True,
               ) -> tuple[np.ndarray, np.ndarray]:
    """(cylinder, flat pixel) pairs whose ray may hit that cylinder, grouped by cylinder in order.

    Conservative culling: the axis is cut into pieces about one radius long; each piece lies
    inside a sphere, and the sphere inside an axis-aligned cube in camera coordinates. x/z and
    y/z are monotonic in each coordinate for z > 0, so the cube's corners bound the piece's
    projection (and of the four, (x - rho)/z bounds below, (x + rho)/z above). Boxes are
    widened by two pixels against float32 rounding in the hit test. A cylinder with a piece
    that reaches the camera plane (z <= 0 somewhere) could project anywhere: every pixel is
    its candidate. A cylinder's candidates on a row are the span from its leftmost to its
    rightmost box there (a superset of the boxes' union). ``cull`` False: every pair (tests).
    """
    n, hw = len(group), h * w
    if not cull:
        return np.repeat(np.arange(n), hw), np.tile(np.arange(hw), n)
    cam = (group.centres - o[None, :]) @ rot                     # rows: rot.T @ (C - o)
    rho = group.rho
    zlo, zhi = cam[:, 2] - rho, cam[:, 2] + rho
    front = zhi > 0                                              # pieces wholly behind cannot be hit (t > 0)
    everywhere = np.zeros(n, bool)
    everywhere[group.owner[front & (zlo <= 1e-6)]] = True
    use = front & ~everywhere[group.owner]
    cam, zlo, zhi, rho, owner = cam[use], zlo[use], zhi[use], rho[use], group.owner[use]
    lo_row = np.full(n * h, w, np.int64)
    hi_row = np.zeros(n * h, np.int64)
    if owner.size:
        cx, cy = principal_point
        bounds = []
        for axis, centre, size in ((0, cx, w), (1, cy, h)):
            near, far = cam[:, axis] - rho, cam[:, axis] + rho
            lo = np.floor(centre + focal_px * np.minimum(near / zlo, near / zhi)).astype(np.int64) - 2
            hi = np.ceil(centre + focal_px * np.maximum(far / zlo, far / zhi)).astype(np.int64) + 2
            bounds.append((np.clip(lo, 0, size), np.clip(hi + 1, 0, size)))
        (j0, j1), (i0, i1) = bounds
        keep = (i0 < i1) & (j0 < j1)
        i0, i1, j0, j1, owner = i0[keep], i1[keep], j0[keep], j1[keep], owner[keep]
        heights = i1 - i0
        first = np.repeat(np.cumsum(heights) - heights, heights)
        rows = np.repeat(owner * h + i0, heights) + (np.arange(first.size) - first)
        np.minimum.at(lo_row, rows, np.repeat(j0, heights))
        np.maximum.at(hi_row, rows, np.repeat(j1, heights))
    lo_row = lo_row.reshape(n, h)
    hi_row = hi_row.reshape(n, h)
    lo_row[everywhere] = 0
    hi_row[everywhere] = w
    counts = np.maximum(hi_row - lo_row, 0).ravel()
    total = int(counts.sum())
    if not total:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    r = np.flatnonzero(counts)
    counts = counts[r]
    starts = (r % h) * w + lo_row.ravel()[r]
    offsets = np.cumsum(counts) - counts
    pix = np.repeat(starts - offsets, counts) + np.arange(total)
    return np.repeat(r // h, counts), pix


def cast_cylinders(group: CylinderGroup, o: np.ndarray, rot: np.ndarray, dirs, focal_px: float,
                   principal_point: tuple[float, float], depth, labels, intensity, objects, light: np.ndarray,
                   bark_scale: float, bark_cos: float, bark_sin: float, sample: Sampler, cull: bool = True) -> None:
    """Cast ``group`` from ``o`` into a view's (H, W) buffers, in place (see the module docstring).

    ``dirs``: the view's ray direction components (H, W) float32; ``sample(texture, u, v)``
    samples a texture at points; ``bark_scale``, ``bark_cos``, ``bark_sin``: how bark is laid
    (texture px per m, the grain's angle).
    """
    if not len(group):
        return
    h, w = depth.shape
    k, pix = candidates(group, o, rot, focal_px, principal_point, h, w, cull)
    if not pix.size:
        return
    d = tuple(a.ravel()[pix] for a in dirs)
    depth_flat = depth.ravel()
    t, s, hits = hit_test(group, o, k, d, depth_flat[pix])
    if not hits.size:
        return
    owner = nearest(len(group), k, pix, t, hits, depth_flat)
    flat = np.flatnonzero(owner >= 0)
    sel = owner[flat]
    hit = (o[0] + t[sel] * d[0][sel], o[1] + t[sel] * d[1][sel], o[2] + t[sel] * d[2][sel])
    kk = k[sel]
    bark = Bark(bark_scale, bark_cos, bark_sin, sample)
    labels.ravel()[flat] = group.kind.take(kk)
    objects.ravel()[flat] = group.objects.take(kk)
    intensity.ravel()[flat] = surface(group, kk, hit, s[sel], light, bark)


def hit_test(group: CylinderGroup, o: np.ndarray, k: np.ndarray, d: tuple[np.ndarray, np.ndarray, np.ndarray],
             depth_at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ray-cylinder test over every (cylinder ``k``, pixel) pair: ``(t, s, hits)``.

    ``d``: the pairs' ray directions (float32); ``depth_at``: the depth already at their
    pixels. ``t``: the distance along the ray to the surface, ``s``: the hit's position along
    the axis from ``p0``, m; ``hits``: the pairs that hit in front of the camera, within the
    cylinder's length and nearer than what is there.
    """
    dx, dy, dz = d
    # Per cylinder (float64, as the one-by-one cast): where the ray starts relative to the axis.
    n = len(group)
    wa = np.empty(n, np.float32)
    wp = np.empty((n, 3), np.float32)
    cc = np.empty(n, np.float32)
    for i, cyl in enumerate(group.cylinders):
        a = group.axis[i]
        wv = o - cyl.p0
        wa_i = float(wv @ a)
        wp_i = wv - wa_i * a                                   # w perpendicular to the axis
        wa[i], wp[i], cc[i] = wa_i, wp_i, np.float32(wp_i @ wp_i - cyl.radius ** 2)
    # Each cylinder's constants over its pairs (pairs are grouped by cylinder: repeat, not gather).
    per = np.bincount(k, minlength=n)
    spread = lambda v: np.repeat(v, per)  # noqa: E731
    a0, a1, a2 = (spread(c) for c in group.axis32.T)
    da = dx * a0 + dy * a1 + dz * a2
    dpx, dpy, dpz = dx - da * a0, dy - da * a1, dz - da * a2
    qa = dpx * dpx + dpy * dpy + dpz * dpz
    wp0, wp1, wp2 = (spread(c) for c in wp.T)
    qb = 2.0 * (dpx * wp0 + dpy * wp1 + dpz * wp2)
    disc = qb * qb - 4.0 * qa * spread(cc)
    ok = disc >= 0
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-qb - np.sqrt(np.where(ok, disc, 0))) / (2.0 * qa)
    s = spread(wa) + t * da
    ok &= (t > 0) & (s >= 0) & (s <= spread(group.length32)) & (t < depth_at)
    return t, s, np.flatnonzero(ok)


def nearest(n: int, k: np.ndarray, pix: np.ndarray, t: np.ndarray, hits: np.ndarray,
            depth_flat: np.ndarray) -> np.ndarray:
    """The depth test, cylinder by cylinder in order: a later one wins a pixel only when strictly nearer.

    Writes the winners' ``t`` into ``depth_flat`` and returns, per pixel, the pair that owns
    it (-1: none of these cylinders).
    """
    owner = np.full(depth_flat.size, -1, np.int64)
    bounds = np.searchsorted(k[hits], np.arange(n + 1))
    for i in range(n):
        e = hits[bounds[i]:bounds[i + 1]]
        if not e.size:
            continue
        e = e[t[e] < depth_flat[pix[e]]]
        depth_flat[pix[e]] = t[e]
        owner[pix[e]] = e
    return owner


@dataclass(frozen=True)
class Bark:
    """How bark is laid on a cylinder: texture px per m, the grain's angle (cos, sin), and the sampler."""

    scale: float
    cos: float
    sin: float
    sample: Sampler


def surface(group: CylinderGroup, kk: np.ndarray, hit: tuple[np.ndarray, np.ndarray, np.ndarray], ss: np.ndarray,
            light: np.ndarray, bark: Bark) -> np.ndarray:
    """The intensity (float32) of the hits on cylinders ``kk`` at world points ``hit``, ``ss`` along their axes:
    albedo, bark texture and shading toward ``light``."""
    pick = lambda v: v.take(kk)  # noqa: E731
    p0x, p0y, p0z = (pick(c) for c in group.p0.T)
    ax0, ax1, ax2 = (pick(c) for c in group.axis.T)
    hx, hy, hz = hit[0] - p0x, hit[1] - p0y, hit[2] - p0z
    nx, ny, nz = hx - ss * ax0, hy - ss * ax1, hz - ss * ax2    # radial vector, length r
    (e10, e11, e12), (e20, e21, e22) = (pick(c) for c in group.e1.T), (pick(c) for c in group.e2.T)
    radius = pick(group.radius)
    ang = np.arctan2(nx * e20 + ny * e21 + nz * e22, nx * e10 + ny * e11 + nz * e12)
    # Bark grain spirals at an irrational angle, so the tile does not repeat along the
    # branch: laid straight it would come back every 0.25 m, inside SGBM's search range for
    # a branch at 1.7 m, where SGBM matches the wrong repeat (a false branch at 0.32 m).
    au, av = ang * radius, ss
    tu = ((au * bark.cos - av * bark.sin) * bark.scale).astype(np.float32)
    tv = ((au * bark.sin + av * bark.cos) * bark.scale).astype(np.float32)
    tex = np.empty(kk.size, np.float32)
    texture = pick(group.texture)
    for tid in np.unique(texture):
        m = texture == tid
        tex[m] = bark.sample(int(tid), tu[m], tv[m])
    shade = 0.35 + 0.65 * np.clip((nx * light[0] + ny * light[1] + nz * light[2]) / radius, 0, 1)
    return (pick(group.albedo32) * (0.45 + 0.55 * tex) * shade).astype(np.float32)
