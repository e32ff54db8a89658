"""The declared pipelines: which stages run, in order, for what flies and for the tuner's faithful mode.

Every pipeline starts with the match (:class:`.matching.MatchStage`: the left and right
SGBM, the measured map and its left-right confidence). What follows is declared, not
switched: a pipeline is a tuple of :class:`Step`, and :data:`FLIGHT`, :data:`FAITHFUL`
and :data:`MEASURED` are the three the project runs.
"""

from __future__ import annotations

import enum

import numpy as np

from uav_depth.core.disparity.fine import FineStage
from uav_depth.core.disparity.matching import MatchStage
from uav_depth.core.disparity.near import NearStage
from uav_depth.core.disparity.result import DisparityResult
from uav_depth.core.params import StereoParams


class Step(enum.Enum):
    """One stage of a disparity pipeline, named by what it adds to :class:`.result.DisparityResult`."""

    #: The left and right SGBM over the window, the left-right confidence: ``measured``, ``confidence``,
    #: ``lr_consistent`` (and ``disparity`` = ``measured`` without WLS).
    MATCH = "match"
    #: OpenCV's WLS smoothing of the map: ``disparity`` (the paper's output; ranging never reads it).
    WLS = "wls"
    #: The near check (:mod:`.near`): objects nearer than the main search can match, ``near``.
    NEAR = "near"
    #: The fine pass ranging may ask for (:mod:`.fine`): ``fine``, where ``compute.fine_disparities`` gives one.
    FINE = "fine"


#: What flies (the daemon, and what the tuner's flown fitnesses score): the match and its confidence, no WLS
#: smoothing (ranging reads the measured pixels alone), the near check and the fine pass.
FLIGHT: tuple[Step, ...] = (Step.MATCH, Step.NEAR, Step.FINE)
#: The paper's pipeline, the tuner's faithful mode: the match and OpenCV's WLS smoothing of it.
FAITHFUL: tuple[Step, ...] = (Step.MATCH, Step.WLS)
#: The measured map and its confidence alone (no smoothing, no near check, no fine pass).
MEASURED: tuple[Step, ...] = (Step.MATCH,)

#: The order stages may be declared in: each reads what the ones before it left.
_ORDER = (Step.MATCH, Step.WLS, Step.NEAR, Step.FINE)


class DisparityPipeline:
    """The declared stages built once from validated parameters.

    ``steps``: :data:`FAITHFUL` (the default: every stage of the paper, WLS smoothing
    included), :data:`FLIGHT` or :data:`MEASURED`, or any tuple of :class:`Step` that
    starts with ``MATCH`` and keeps their order. WLS runs only when ``wls.enabled``;
    the fine pass only where the parameters have one. Not thread-safe (OpenCV matcher
    objects keep state): build one per thread or process. Building is cheap (well under
    a millisecond).
    """

    def __init__(self, params: StereoParams, steps: tuple[Step, ...] = FAITHFUL):
        steps = tuple(steps)
        if not steps or steps[0] is not Step.MATCH or list(steps) != sorted(set(steps), key=_ORDER.index):
            raise ValueError(f"a pipeline's steps must start with MATCH and declare each of "
                             f"{', '.join(s.name for s in _ORDER)} at most once, in that order, but got "
                             f"{[s.name for s in steps]}")
        self.params = params
        self.steps = steps
        self.match = MatchStage(params, smooth=Step.WLS in steps)
        after = []
        if Step.NEAR in steps:
            after.append(NearStage(params))
        if Step.FINE in steps and params.compute.fine_pass:
            after.append(FineStage(params))
        self.after: tuple[NearStage | FineStage, ...] = tuple(after)

    def run(self, left: np.ndarray, right: np.ndarray) -> DisparityResult:
        """Disparity of a rectified pair (uint8 grey or BGR colour, same shape).

        Every map is (H, W) at the input's resolution whatever ``compute.*`` says;
        outside ``compute.roi`` disparities are NaN and confidence is 0. A window
        too narrow for the disparity search gives all-NaN maps (nothing matched).
        """
        result = self.match.run(left, right).result
        for stage in self.after:
            result = stage.run(left, right, result)
        return result

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(H, W) float32 disparity in px of the left image, NaN where invalid."""
        return self.run(left, right).disparity


def flight_pipeline(params: StereoParams) -> DisparityPipeline:
    """What flies (:data:`FLIGHT`): the measured map, its confidence, the near check and the fine pass."""
    return DisparityPipeline(params, FLIGHT)
