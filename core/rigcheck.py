"""Rig check: is a rectified stereo pair still rectified?

SGBM searches each left-image row along the *same* row of the right image. When a
knock or heat moves a camera, the rows no longer line up and matching fails long
before anything looks wrong. This measures the misalignment from feature matches:

1. SIFT keypoints in both images, matched with Lowe's ratio test (0.75) and a
   cross-check; matches whose row offset exceeds ``search_px`` are dropped (a row
   offset that large is a wrong match, or a rig so far off that the check says so
   by finding too few matches);
2. each match is refined to sub-pixel by Lucas-Kanade (21x21 window) from SIFT's
   position, and kept only when tracking back lands within 0.1 px of where it
   started, and only at corners (both eigenvalues of the structure tensor within 5x
   of each other: along an edge a row offset is indistinguishable from a disparity
   change) (SIFT's own positions carry ~0.1-0.3 px noise, and a 0.5 px misalignment
   must be read to 0.1 px);
3. the vertical offset (right row - left row, px) is summarised by its median and
   its spread (1.4826 x MAD), and fitted as a plane over the image (a rotation
   between the cameras makes it vary from one side to the other), and the horizontal
   offset (left x - right x = disparity, px) by its median and 5th..95th percentiles.

Threshold (:data:`MAX_VERTICAL_PX` = 0.5 px): SGBM's default 5 px block sees a
0.5 px row shift as a little blur; measured on synthetic scenes and on Middlebury
2006 pairs (``bench/rigcheck_sgbm.py``), the valid share and the error of SGBM stay
close to those of the aligned pair up to 0.5 px and degrade past it (docs/rigcheck.md
has the figures). So: within 0.5 px everywhere the rig is fine, beyond it re-calibrate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uav_depth.core.errors import FrameError

#: Largest vertical misalignment (|median| and the worst corner of the fitted plane), px,
#: at which SGBM still matches as on an aligned pair. See the module docstring.
MAX_VERTICAL_PX = 0.5
#: Fewest good matches needed to say anything.
MIN_MATCHES = 30
_PATCH = 32
_WIN = 21     # Lucas-Kanade window, px
_MIN_EIG_RATIO = 0.2   # smaller / larger eigenvalue of the structure tensor: a corner, not an edge


@dataclass(frozen=True)
class RigCheck:
    """The rig check of one pair (or several pooled). Offsets in px, right minus left for rows.

    ``vertical_median_px``: median row offset; ``vertical_spread_px``: 1.4826 x its MAD;
    ``vertical_corners_px``: the fitted plane's offset at the four image corners
    (top-left, top-right, bottom-left, bottom-right); ``horizontal_*``: disparity (left x -
    right x) median and 5th / 95th percentiles; ``ok``: None when there were too few matches.
    """

    n_matches: int
    vertical_median_px: float
    vertical_spread_px: float
    vertical_corners_px: tuple[float, float, float, float]
    horizontal_median_px: float
    horizontal_p5_px: float
    horizontal_p95_px: float
    threshold_px: float
    ok: bool | None

    @property
    def vertical_worst_px(self) -> float:
        return max(abs(self.vertical_median_px), *(abs(c) for c in self.vertical_corners_px))

    def verdict(self) -> str:
        """One line an operator reads."""
        if self.ok is None:
            return (f"cannot tell: only {self.n_matches} feature matches (need {MIN_MATCHES}); point the rig at "
                    "something textured")
        v = (f"vertical misalignment {self.vertical_median_px:+.2f} px median (spread {self.vertical_spread_px:.2f}, "
             f"worst corner {self.vertical_worst_px:.2f} px) over {self.n_matches} matches; horizontal offset "
             f"{self.horizontal_median_px:.1f} px median ({self.horizontal_p5_px:.1f}..{self.horizontal_p95_px:.1f})")
        if self.ok:
            return f"OK, SGBM can work: {v}; threshold {self.threshold_px:g} px"
        return (f"MISALIGNED, SGBM will fail: {v} exceeds {self.threshold_px:g} px; re-calibrate the rig "
                "(or check that the calibration matches this camera)")


def _grey(img: np.ndarray) -> np.ndarray:
    import cv2

    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def match_offsets(left: np.ndarray, right: np.ndarray, search_px: float = 8.0,
                  max_features: int = 2000) -> np.ndarray:
    """(N, 4) float64 of matches: left x, left y, dx (left x - right x), dy (right y - left y), px.

    ``left``/``right``: rectified (H, W[, 3]) images of the same size.
    """
    import cv2

    if left.shape[:2] != right.shape[:2]:
        raise FrameError(f"left {left.shape[1]}x{left.shape[0]} and right {right.shape[1]}x{right.shape[0]} "
                         "images differ in size")
    h, w = left.shape[:2]
    if min(h, w) < 2 * _PATCH:
        raise FrameError(f"images of {w}x{h} are too small for a rig check (need at least {2 * _PATCH} px a side)")
    gl, gr = _grey(left), _grey(right)
    sift = cv2.SIFT_create(nfeatures=max_features)
    kl, dl = sift.detectAndCompute(gl, None)
    kr, dr = sift.detectAndCompute(gr, None)
    if dl is None or dr is None or len(kl) < 2 or len(kr) < 2:
        return np.zeros((0, 4))
    bf = cv2.BFMatcher(cv2.NORM_L2)
    fwd = bf.knnMatch(dl, dr, k=2)
    back = {m.queryIdx: m.trainIdx for m in bf.match(dr, dl)}   # cross-check: right's best back to left
    pl, pr = [], []
    for pair in fwd:
        if len(pair) < 2 or pair[0].distance > 0.75 * pair[1].distance:
            continue
        m = pair[0]
        if back.get(m.trainIdx) != m.queryIdx:
            continue
        xl, yl = kl[m.queryIdx].pt
        xr, yr = kr[m.trainIdx].pt
        if abs(yr - yl) <= search_px:
            pl.append((xl, yl))
            pr.append((xr, yr))
    if not pl:
        return np.zeros((0, 4))
    p0 = np.array(pl, np.float32).reshape(-1, 1, 2)
    p1 = np.array(pr, np.float32).reshape(-1, 1, 2)
    # Lucas-Kanade from SIFT's match, both ways: iterative and interpolating, it reads a sub-pixel
    # shift without the pull toward whole pixels that SIFT's or phase correlation's peaks have.
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 0.001)
    lk = {"winSize": (_WIN, _WIN), "maxLevel": 0, "criteria": crit, "flags": cv2.OPTFLOW_USE_INITIAL_FLOW}
    q1, st1, _ = cv2.calcOpticalFlowPyrLK(gl, gr, p0, p1.copy(), **lk)
    q0, st0, _ = cv2.calcOpticalFlowPyrLK(gr, gl, q1, p0.copy(), **lk)
    good = ((st1.ravel() == 1) & (st0.ravel() == 1)
            & (np.linalg.norm((q0 - p0).reshape(-1, 2), axis=1) < 0.1)     # forward-backward agree
            & (np.linalg.norm((q1 - p1).reshape(-1, 2), axis=1) < 2.0))    # LK stayed on SIFT's match
    # Only corners: on a straight edge (a branch) a row offset and a disparity change look the same
    # (the aperture problem), so a point whose structure tensor is not two-dimensional says nothing.
    eig = cv2.cornerEigenValsAndVecs(gl, _WIN, 3)
    ix = np.clip(np.round(p0.reshape(-1, 2)).astype(int), 0, [w - 1, h - 1])
    l1, l2 = eig[ix[:, 1], ix[:, 0], 0], eig[ix[:, 1], ix[:, 0], 1]
    good &= np.minimum(l1, l2) >= _MIN_EIG_RATIO * np.maximum(l1, l2)
    a, b = p0.reshape(-1, 2)[good].astype(np.float64), q1.reshape(-1, 2)[good].astype(np.float64)
    inside = (b[:, 0] >= _WIN) & (b[:, 0] < w - _WIN) & (b[:, 1] >= _WIN) & (b[:, 1] < h - _WIN)
    a, b = a[inside], b[inside]
    rows = np.column_stack([a[:, 0], a[:, 1], a[:, 0] - b[:, 0], b[:, 1] - a[:, 1]])
    return np.array(rows, np.float64).reshape(-1, 4)


def summarise(offsets: np.ndarray, width: int, height: int, threshold_px: float = MAX_VERTICAL_PX) -> RigCheck:
    """The :class:`RigCheck` of pooled :func:`match_offsets` rows from ``width`` x ``height`` images."""
    n = len(offsets)
    if n < MIN_MATCHES:
        nan = math.nan
        return RigCheck(n, nan, nan, (nan, nan, nan, nan), nan, nan, nan, threshold_px, None)
    x, y, dx, dy = offsets.T
    med = float(np.median(dy))
    spread = float(1.4826 * np.median(np.abs(dy - med)))
    keep = np.abs(dy - med) <= max(3 * spread, 0.5)     # the plane is fitted to the inliers
    a = np.column_stack([np.ones(keep.sum()), x[keep] / width - 0.5, y[keep] / height - 0.5])
    coef, *_ = np.linalg.lstsq(a, dy[keep], rcond=None)
    corners = tuple(float(coef[0] + coef[1] * cx + coef[2] * cy)
                    for cy in (-0.5, 0.5) for cx in (-0.5, 0.5))
    check = RigCheck(n, med, spread, corners, float(np.median(dx)), float(np.percentile(dx, 5)),
                     float(np.percentile(dx, 95)), threshold_px, None)
    ok = check.vertical_worst_px <= threshold_px
    return RigCheck(n, med, spread, corners, check.horizontal_median_px, check.horizontal_p5_px,
                    check.horizontal_p95_px, threshold_px, ok)


def check_rig(left: np.ndarray, right: np.ndarray, threshold_px: float = MAX_VERTICAL_PX) -> RigCheck:
    """Rig check of one rectified pair."""
    return summarise(match_offsets(left, right), left.shape[1], left.shape[0], threshold_px)
