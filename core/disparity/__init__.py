"""The disparity stage: OpenCV SGBM, a right matcher, a left-right confidence and, as declared, WLS, the near
check and the fine pass.

This is the one disparity path of the project: the daemon flies it and the tuner
scores it. Build :class:`DisparityPipeline` from validated :class:`StereoParams` and
a declared list of steps (:mod:`.pipeline`: :data:`FLIGHT`, :data:`FAITHFUL`,
:data:`MEASURED`); ``run`` maps a rectified pair to a :class:`DisparityResult` of
(H, W) float32 maps at the input's resolution. The modules follow the stages, each a
small function or object of frozen inputs:

* :mod:`.window`: which crop of the input answers ``compute.roi`` (the full
  frame is a window like any other) and at which matched size;
* :mod:`.prepare`: check the pair, crop, grey (``compute.grey``), resize
  (``compute.scale``);
* :mod:`.match`: the left SGBM and, when ``wls.enabled``, the right one;
* :mod:`.confidence`: the left-right confidence (OpenCV's WLS definition);
* :mod:`.matching`: the match stage that runs those, OpenCV's WLS smoothing at the input or
  matched resolution (``compute.wls_at``) when declared (``Step.WLS``: the tuner's faithful
  mode; the daemon ranges on ``measured`` + ``confidence`` and flies without it), and puts the
  region back into full-size maps, disparities in input px;
* :mod:`.near` and :mod:`.fine`, in the flight pipeline: a coarse pass for objects nearer than the
  search, and a full-resolution re-match of the box ranging asks for (``DisparityResult.fine``);
* :mod:`.result`: the typed results.

Outside the region disparities are NaN and confidence is 0. With the default
parameters the pipeline computes exactly OpenCV's sample (full frame, full
resolution, colour as given).
"""

from __future__ import annotations

from uav_depth.core.disparity.pipeline import FAITHFUL, FLIGHT, MEASURED, DisparityPipeline, Step, flight_pipeline
from uav_depth.core.disparity.prepare import check_pair
from uav_depth.core.disparity.result import DisparityResult, FineMatch, FineRematch, NearCheck

__all__ = ["DisparityPipeline", "DisparityResult", "FAITHFUL", "FLIGHT", "FineMatch", "FineRematch", "MEASURED",
           "NearCheck", "Step", "check_pair", "flight_pipeline"]
