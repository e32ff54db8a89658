"""What the renderer hands back: a rig pose and one rendered stereo frame with its exact truth."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uav_depth.sim.geometry import BRANCH
from uav_depth.sim.truth import Truth, nearest_significant


@dataclass(frozen=True)
class Pose:
    """Rig pose in the world: ``rotation`` (3, 3) camera axes as columns, ``position`` (3,) m."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @staticmethod
    def forward(distance_m: float) -> "Pose":
        """The identity pose moved ``distance_m`` along the optical axis (toward the tree)."""
        return Pose(np.eye(3), np.array([0.0, 0.0, float(distance_m)]))


@dataclass(frozen=True)
class StereoFrame:
    """One rendered pair. Images uint8 (H, W) grey or (H, W, 3) BGR.

    ``disparity``: (H, W) float32 px of the left view (exact; 0 on the sky); ``depth``:
    (H, W) float32 m along the optical axis (inf on the sky); ``labels``: (H, W)
    uint8 (0 background, 1 trunk, 2 branch, 3 twig, 4 needle, 5 sky); ``objects``:
    (H, W) int16 object index of the left view (-1 sky, 0 background plane, i + 1
    the scene's cylinder i) and ``thickness_m`` (n_objects,) each object's thickness,
    for :meth:`truth`. With ``rect_error_px`` e the right view is e px off: left
    (x, y) corresponds to right (x - d, y + e).
    """

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    depth: np.ndarray
    labels: np.ndarray
    objects: np.ndarray | None = None
    thickness_m: np.ndarray | None = None
    focal_px: float | None = None

    def truth(self, roi: tuple[int, int, int, int] | None = None) -> Truth:
        """The nearest significant object in ``roi`` (:mod:`uav_depth.sim.truth`)."""
        if self.objects is None or self.thickness_m is None or self.focal_px is None:
            raise ValueError("this frame carries no object map: render it with Scene.render")
        return nearest_significant(self.depth, self.objects, self.thickness_m, self.focal_px, roi)

    @property
    def branch_mask(self) -> np.ndarray:
        return self.labels == BRANCH

    def nearest_branch_distance(self, roi: tuple[int, int, int, int] | None = None) -> float:
        """Distance along the optical axis to the nearest branch surface in ``roi`` (NaN if none)."""
        return nearest_distance(self.depth, self.branch_mask, roi)


def nearest_distance(depth: np.ndarray, mask: np.ndarray, roi: tuple[int, int, int, int] | None) -> float:
    if roi is not None:
        x0, y0, x1, y1 = roi
        depth, mask = depth[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    vals = depth[mask]
    return float(vals.min()) if vals.size else float("nan")


#: A part of the image: (x0, y0, x1, y1) px.
View = tuple[int, int, int, int]


def window_views(width: int, height: int, window: View | None, reach_px: float) -> tuple[View, View]:
    """(the window, what to ray-cast for it): ``window`` (None: the whole image) and, for a window, it
    grown by ``reach_px`` (+1) on each side within the image: what the optical blur mixes into it.

    A window render is a full render's pixels inside the window (the same per-pixel arithmetic; the
    sensor noise is drawn afresh), and blank outside (images 0, depth inf, labels sky, objects -1).
    """
    if window is None:
        return (0, 0, width, height), (0, 0, width, height)
    x0, y0, x1, y1 = (int(v) for v in window)
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise ValueError(f"window {list(window)} must lie inside the {width}x{height} image")
    pad = int(math.ceil(reach_px)) + 1
    return (x0, y0, x1, y1), (max(0, x0 - pad), max(0, y0 - pad), min(width, x1 + pad), min(height, y1 + pad))


def shifted(point: tuple[float, float], view: View) -> tuple[float, float]:
    """An image point in the coordinates of ``view``'s buffers."""
    return point[0] - view[0], point[1] - view[1]


def paste(part: np.ndarray, view: View, inner: View, size: tuple[int, int], fill) -> np.ndarray:
    """The ``inner`` window of ``part`` (rendered over ``view``) in a full-size map filled with ``fill``."""
    full = np.full(size + part.shape[2:], fill, part.dtype)
    x0, y0, x1, y1 = inner
    full[y0:y1, x0:x1] = part[y0 - view[1]:y1 - view[1], x0 - view[0]:x1 - view[0]]
    return full
