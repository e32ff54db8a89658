"""Fine pass: re-match one box at full resolution over a narrow disparity search.

With ``compute.scale`` < 1 the whole region is matched coarsely (half scale leaves
an object at 3 m about 7 matched px of disparity at 1280x720, 2 px at 5 m and
640x360, and loses thin structure on real optics). Ranging finds the front object
and its box on that coarse map, then asks this stage to match only the box, at the
input resolution, over ``compute.fine_disparities`` disparities starting at a
given ``d0`` (input px) just below the coarse disparity. Ranging decides what the
fine match may change (``uav_depth.core.ranging``: never farther than the coarse
pass saw unless the fine match is confident).

The search is shifted instead of widened: the right crop is taken ``d0`` columns
left of the left crop, so SGBM searches 0 .. num - 1 on the shifted pair and the
true disparity is that plus ``d0``. The crop then needs only ``num`` columns of
margin on each side (the left search band; the right matcher's unanswered band for
the left-right check), not ``d0 + num``. What it costs is set by the box ranging
asks for (``uav_depth.core.ranging`` caps it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from uav_depth.core.disparity.confidence import lr_confidence
from uav_depth.core.disparity.match import build_matchers, match_left, match_right, to_float
from uav_depth.core.disparity.result import Box, DisparityResult, FineMatch
from uav_depth.core.disparity.window import context_px
from uav_depth.core.params import StereoParams


def fine_params(params: StereoParams) -> StereoParams:
    """The fine pass's parameters: the main ones at full resolution, searching ``compute.fine_disparities``
    from 0 (the shift adds the rest)."""
    return params.replace(**{"compute.scale": 1.0, "compute.roi": (0.0, 0.0, 1.0, 1.0),
                             "compute.fine_disparities": 0, "sgbm.min_disparity": 0,
                             "sgbm.num_disparities": params.compute.fine_disparities})


class FineMatcher:
    """The fine pass's matchers, built once from validated parameters (not thread-safe, as SGBM)."""

    def __init__(self, params: StereoParams):
        self.params = fine_params(params)
        self.grey = params.compute.grey
        self.num = params.compute.fine_disparities
        self.matchers = build_matchers(self.params)

    def match(self, left: np.ndarray, right: np.ndarray, box: Box, d0: int) -> FineMatch | None:
        """Match ``box`` of the rectified pair over disparities ``d0 .. d0 + num - 1`` (input px).

        None when the box is too near the image's left edge for the shifted search
        (the crop would not be wider than the search).
        """
        h, w = left.shape[:2]
        x0, y0, x1, y1 = box
        d0 = max(0, int(d0))
        sg = self.params.sgbm
        context = context_px(self.params)
        margin = self.num + context
        cx0 = max(x0 - margin, d0)                  # the right crop starts d0 columns left: not before 0
        cx1 = min(w, x1 + (margin if self.matchers.right is not None else context))
        cy0, cy1 = max(0, y0 - context), min(h, y1 + context)
        if cx1 - cx0 <= self.num + sg.block_size // 2 or x1 <= cx0 + self.num:
            return None
        lc, rc = left[cy0:cy1, cx0:cx1], right[cy0:cy1, cx0 - d0:cx1 - d0]
        if self.grey and lc.ndim == 3:
            lc, rc = cv2.cvtColor(lc, cv2.COLOR_BGR2GRAY), cv2.cvtColor(rc, cv2.COLOR_BGR2GRAY)
        lc, rc = np.ascontiguousarray(lc), np.ascontiguousarray(rc)
        left16 = match_left(self.matchers, lc, rc)
        # The box in the crop; columns of the box left of the crop (nearer the image's edge than d0) stay NaN.
        ix0 = max(x0, cx0)
        inner = (slice(y0 - cy0, y1 - cy0), slice(ix0 - cx0, x1 - cx0))
        measured = np.full((y1 - y0, x1 - x0), np.nan, np.float32)
        measured[:, ix0 - x0:] = to_float(left16, 0)[inner] + np.float32(d0)
        conf = None
        if self.matchers.right is not None:
            conf = np.zeros((y1 - y0, x1 - x0), np.float32)
            # Over the box's columns only (each value the whole crop's map would hold, lr_confidence's cols).
            conf[:, ix0 - x0:] = np.clip(lr_confidence(left16, match_right(self.matchers, lc, rc), self.params.sgbm,
                                                       cols=(ix0 - cx0, x1 - cx0))[inner] * np.float32(1.0 / 255.0),
                                         0.0, 1.0)
        return FineMatch(box, measured, conf, float(d0), float(d0 + self.num - 1))


@dataclass(frozen=True)
class FineOnFrame:
    """The fine pass offered to ranging for one frame (:class:`.result.FineRematch`): this frame's pair and
    the fine matcher. Nothing is matched until ranging asks for a box."""

    matcher: FineMatcher
    left: np.ndarray
    right: np.ndarray

    def match(self, box: Box, d0: int) -> FineMatch | None:
        return self.matcher.match(self.left, self.right, box, d0)


class FineStage:
    """The fine pass as a stage of the flight pipeline: adds :class:`FineOnFrame` to a result that matched.
    Built only where the parameters have a fine pass (:attr:`~uav_depth.core.params.ComputeParams.fine_pass`:
    at ``compute.scale`` 1 the main match is already full resolution)."""

    def __init__(self, params: StereoParams):
        self.matcher = FineMatcher(params)

    def run(self, left: np.ndarray, right: np.ndarray, result: DisparityResult) -> DisparityResult:
        if result.warning:
            return result
        return replace(result, fine=FineOnFrame(self.matcher, left, right))
