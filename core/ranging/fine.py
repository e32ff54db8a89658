"""The fine pass in ranging: the coarse reading re-measured on a full-resolution match of the object's box
(:mod:`uav_depth.core.disparity.fine` matches; this decides what the match may change: never farther than the
coarse pass saw on a fine match that does not hold up)."""

from __future__ import annotations

import math

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging.frame import RangingFrame
from uav_depth.core.ranging.measurement import Measurement
from uav_depth.core.ranging.nearest import NearestObject, find, reading, shift, usable
from uav_depth.core.ranging.setup import Setup
from uav_depth.core.ranging.stats import count_median

#: The fine pass (``compute.fine_disparities``) searches from this share of its range below the coarse
#: disparity: most of it above, where a coarse reading that was too far (the unsafe error) finds its object.
FINE_BELOW_REL = 0.25
#: The fine object's band is widened by this much for matching noise, input px (the coarse pass: one
#: matched px). Full-resolution SGBM is good to a few tenths of a pixel; at 5 m and f*B = 22 px*m one
#: pixel is a metre of depth, and a wider band takes in the trunk behind the branch.
FINE_MARGIN_PX = 0.5
#: A fine reading farther than the coarse one replaces it only within this many coarse matched px: half a
#: pixel, the coarse pass's own rounding (a whole one let a leafy frame at 2.3 m read 6 % farther,
#: docs/ranging.md, *Fine pass*).
FINE_FARTHER_PX = 0.5
#: The fine pass matches at most this many input columns and rows (plus its search margins), around the
#: pixels that decide the reading: its cost stays bounded whatever the object's size (docs/ranging.md,
#: *Fine pass*).
FINE_MAX_COLS = 160
FINE_MAX_ROWS = 96
#: ... or, for an object wider than FINE_MAX_COLS, up to twice as many columns with as many fewer rows (never
#: under this many): the same area, so that a branch seen obliquely keeps its near end in the fine pass.
FINE_MIN_ROWS = 16


def fine_pass(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: where the pipeline offers a fine pass, the reading re-measured on it (:func:`refine`)."""
    if f.result.fine is not None:
        assert f.reading is not None and f.obj is not None
        f.reading = refine(s, f.reading, f.obj, f.result, f.disp, f.ok)
    return None


def refine(s: Setup, m: Measurement, obj: NearestObject, result: DisparityResult, disp: np.ndarray,
           ok: np.ndarray) -> Measurement:
    """The coarse reading ``m`` re-measured on the fine pass (:mod:`uav_depth.core.disparity.fine`).

    The object's box (one coarse pixel more all round, inside the ROI) is matched at
    full resolution from :data:`FINE_BELOW_REL` of the search below the coarse
    disparity. Every pixel counts except those the coarse pass measured confidently
    behind the object: measured at the object's depth or nearer, measured with low
    confidence, or not measured at all (a thin twig in front is often lost at half
    scale, or matched there with the low confidence the depth-edge weight gives a
    pixel that is all edge; so are the columns SGBM leaves unanswered). The narrow
    search would match the background around a thin branch to something inside it,
    and without a right matcher nothing in the fine pass tells such a match from a
    true one.
    Fine pixels at the search's lower end (farther than searched) do not count
    either. The fine object (its front and its own band) needs as many pixels as a
    coarse one (``min_valid_px`` coarse matched pixels): the same image area, not a
    smaller speckle.

    The fine object replaces the coarse one when it is nearer (nearer is always
    safe), or farther but confident: within half a coarse matched pixel of the
    coarse disparity (the coarse pass's own rounding) and measured at least as
    tightly (its spread sigma_d no larger). Otherwise the coarse reading stands:
    never farther than what the coarse pass saw on a fine match that does not hold
    up.
    """
    assert result.fine is not None
    x0, y0, x1, y1 = s.roi
    pad = int(math.ceil(s.px))
    bx0, by0, bx1, by1 = obj.bbox
    bx0, by0, bx1, by1 = max(0, bx0 - pad), max(0, by0 - pad), min(x1 - x0, bx1 + pad), min(y1 - y0, by1 + pad)
    # Columns beside the box where the coarse pass measured nothing at all in the box's rows (e.g. the
    # band SGBM leaves unanswered at the image's left edge, wider than the object's own disparity
    # needs) may hold a nearer part of the object: the fine pass looks there too.
    seen = np.isfinite(disp[by0:by1]).any(axis=0)
    ox0, ox1 = bx0, bx1
    while bx0 > 0 and not seen[bx0 - 1]:
        bx0 -= 1
    while bx1 < seen.size and not seen[bx1]:
        bx1 += 1
    # The window keeps the unseen columns (the side they are on), else centres on the front pixels.
    anchor = "left" if bx0 < ox0 else "right" if bx1 > ox1 else None
    with np.errstate(invalid="ignore"):
        front = ok[by0:by1, bx0:bx1] & (disp[by0:by1, bx0:bx1] >= obj.d)
    bx0, by0, bx1, by1 = fine_window((bx0, by0, bx1, by1), front, anchor)
    num = s.params.compute.fine_disparities
    d0 = max(0, int(math.floor(obj.d - FINE_BELOW_REL * num)))
    fm = result.fine.match((bx0 + x0, by0 + y0, bx1 + x0, by1 + y0), d0)
    if fm is None:
        return m
    box = (slice(by0, by1), slice(bx0, bx1))
    with np.errstate(invalid="ignore"):
        mine = ~(ok[box] & (disp[box] < obj.lower))      # all but what the coarse pass saw confidently behind
        fok = usable(s, fm.measured, fm.confidence) & (fm.measured >= fm.d_lo + 1.0) & mine
    fobj = find(s, fm.measured, fm.confidence, fok, 1.0, s.px, FINE_MARGIN_PX, slant_cap=obj.front)
    if fobj is None or fobj.n < s.config.min_valid_px * s.px * s.px:
        return m
    if fobj.d < obj.d and not (obj.d - fobj.d <= FINE_FARTHER_PX * s.px and fobj.sigma_d <= obj.sigma_d):
        return m
    return reading(s, fobj, shift(fobj.bbox, bx0 + x0, by0 + y0), m.quality, m.valid_fraction, refined=True)


def fine_window(box: tuple[int, int, int, int], front: np.ndarray,
                anchor: str | None = None) -> tuple[int, int, int, int]:
    """``box`` (ROI coordinates) cut to at most FINE_MAX_COLS x FINE_MAX_ROWS (a wider box: up to twice the
    columns with the rows cut to keep the area, at least FINE_MIN_ROWS) around the median of the
    ``front`` pixels in it (those that decide the reading), or along the ``anchor`` side ("left",
    "right"): the fine pass's cost stays bounded. ``front``: the box's own pixels."""
    bx0, by0, bx1, by1 = box
    # The front pixels' median column and row from their counts per column and per row (as the slant window's).
    per_row = np.count_nonzero(front, axis=1)
    if not per_row.any():
        return box
    cx, cy = bx0 + int(count_median(np.count_nonzero(front, axis=0))), by0 + int(count_median(per_row))
    if anchor == "left":
        cx = bx0 + FINE_MAX_COLS // 2
    elif anchor == "right":
        cx = bx1 - FINE_MAX_COLS // 2

    def cut(lo: int, hi: int, c: int, n: int) -> tuple[int, int]:
        if hi - lo <= n:
            return lo, hi
        start = min(max(lo, c - n // 2), hi - n)
        return start, start + n

    cols = max(FINE_MAX_COLS, min(bx1 - bx0, 2 * FINE_MAX_COLS))
    rows = max(FINE_MIN_ROWS, min(FINE_MAX_ROWS, (FINE_MAX_COLS * FINE_MAX_ROWS) // cols))
    (bx0, bx1), (by0, by1) = cut(bx0, bx1, cx, cols), cut(by0, by1, cy, rows)
    return bx0, by0, bx1, by1
