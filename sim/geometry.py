"""Scene geometry shared by the renderer and its parts: surface labels, cylinders, hard shadows.

Labels (``StereoFrame.labels``): 0 background plane, 1 trunk, 2 branch (the target
and the other branches, small front branches too), 3 twig (3-10 mm), 4 needle,
5 sky (at infinity: depth inf, disparity 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

BACKGROUND, TRUNK, BRANCH, TWIG, NEEDLE, SKY = 0, 1, 2, 3, 4, 5

#: Direction toward the sun that casts the hard shadows: above and behind the
#: camera, so foliage in front throws its shadow onto the branch, the trunk and
#: the canopy behind it.
SUN = np.array([0.25, -0.35, -1.0]) / np.linalg.norm([0.25, -0.35, -1.0])


@dataclass(frozen=True)
class Cylinder:
    p0: np.ndarray      # (3,) start of the axis, world m
    axis: np.ndarray    # (3,) unit direction
    length: float
    radius: float
    kind: int           # TRUNK, BRANCH, TWIG or NEEDLE
    texture: int        # index into the scene's textures
    albedo: float

    @property
    def thickness_m(self) -> float:
        return 2.0 * self.radius

    def pieces(self) -> tuple[np.ndarray, float, float]:
        """Centres (n, 3) of axis pieces, their length and the radius of a sphere around each.

        Pieces are about one radius long, but a thin cylinder (a needle: 0.5 mm
        radius, 12 cm long) is cut into at most 32 pieces so that culling it stays
        cheap; culling only needs each piece inside its sphere.
        """
        n = max(1, math.ceil(self.length / self.radius))
        if self.radius < 0.005:
            n = min(n, 32)
        step = self.length / n
        centres = self.p0[None, :] + ((np.arange(n) + 0.5) * step)[:, None] * self.axis[None, :]
        return centres, step, math.hypot(step / 2.0, self.radius)


class ShadowMap:
    """Hard shadows from the sun (:data:`SUN`), cast by ``occluders`` onto every surface.

    An orthographic height map along the sun direction: map pixel (u, v) holds the
    largest sun-ward height of any occluder piece over it and which object it is.
    A surface point is in shadow when another object lies over it more than 2 mm
    nearer the sun. The map covers the footprint of ``extent`` (default: all
    occluders; the foliage, where there is some, and 10 cm around it) at ``res_m``
    per pixel (1 mm: a needle's shadow is one pixel wide) or coarser if the footprint
    is over ``max_px`` wide; shadows are exact to that resolution and to the pieces'
    2 cm length, and do not depend on the pose, so they are built once per scene.
    """

    EPS_M = 0.002

    def __init__(self, occluders: list[tuple[int, Cylinder]], extent: list[tuple[int, Cylinder]] | None = None,
                 res_m: float = 0.001, max_px: int = 2048):
        self.e1 = np.cross(SUN, [0.0, 1.0, 0.0])
        self.e1 /= np.linalg.norm(self.e1)
        self.e2 = np.cross(SUN, self.e1)
        segs = []
        for obj, cyl in occluders:
            n = max(1, math.ceil(cyl.length / 0.02))
            s = np.linspace(0.0, cyl.length, n + 1)
            pts = cyl.p0[None, :] + s[:, None] * cyl.axis[None, :]
            for a, b in zip(pts[:-1], pts[1:]):
                segs.append((float((a + b) @ SUN) / 2.0 + cyl.radius, obj, a, b, cyl.radius))
        self.empty = not segs
        if self.empty:
            return
        ext = extent if extent is not None else occluders
        ends = np.array([p for _, cyl in ext for p in (cyl.p0, cyl.p0 + cyl.axis * cyl.length)])
        uv = np.stack([ends @ self.e1, ends @ self.e2], axis=1)
        pad = 0.1 if extent is not None else 0.02
        lo, hi = uv.min(axis=0) - pad, uv.max(axis=0) + pad
        self.res = max(res_m, float((hi - lo).max()) / max_px)
        self.lo = lo
        size = np.ceil((hi - lo) / self.res).astype(int) + 1
        self.height = np.full((size[1], size[0]), -np.inf, np.float32)
        self.owner = np.full((size[1], size[0]), -1.0, np.float32)
        # Drawn in rising height, so each map pixel keeps the highest (sun-most) occluder.
        for h, obj, a, b, r in sorted(segs, key=lambda s: s[0]):
            pa, pb = self._px(a), self._px(b)
            thick = max(1, int(round(2.0 * r / self.res)))
            cv2.line(self.height, pa, pb, float(h), thick, cv2.LINE_8)
            cv2.line(self.owner, pa, pb, float(obj), thick, cv2.LINE_8)

    def _px(self, p: np.ndarray) -> tuple[int, int]:
        return (int(round((p @ self.e1 - self.lo[0]) / self.res)), int(round((p @ self.e2 - self.lo[1]) / self.res)))

    def shadowed(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, obj: np.ndarray) -> np.ndarray:
        """Which world points (x, y, z: (n,) m) of objects ``obj`` (n,) lie in another object's shadow."""
        if self.empty:
            return np.zeros(x.shape, bool)
        e1, e2 = self.e1, self.e2
        u = np.rint((x * e1[0] + y * e1[1] + z * e1[2] - self.lo[0]) / self.res).astype(np.int64)
        v = np.rint((x * e2[0] + y * e2[1] + z * e2[2] - self.lo[1]) / self.res).astype(np.int64)
        h = x * SUN[0] + y * SUN[1] + z * SUN[2]
        inside = (u >= 0) & (v >= 0) & (u < self.height.shape[1]) & (v < self.height.shape[0])
        out = np.zeros(x.shape, bool)
        ui, vi = u[inside], v[inside]
        out[inside] = (self.height[vi, ui] > h[inside] + self.EPS_M) & (self.owner[vi, ui] != obj[inside]) \
            & (self.owner[vi, ui] >= 0)
        return out
