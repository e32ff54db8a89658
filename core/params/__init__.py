"""The stereo parameters: one definition, used by the daemon, the tuner and the CLI.

* :mod:`.schema`: every key of the parameter file declared once (:data:`SPECS`), the frozen
  :class:`StereoParams` and its validation (:func:`params_from_dict`);
* :mod:`.checks`: rules that need more than one key or the image size, and a camera's search range;
* :mod:`.file`: reading (strictly) and writing parameter files;
* :mod:`.flight`: the recommended flight settings, read from the files the project ships.
"""

from __future__ import annotations

from uav_depth.core.params.checks import check_computable, check_image_size, disparity_search_range
from uav_depth.core.params.file import dump_params, load_params, read_provenance, save_params
from uav_depth.core.params.schema import (ABOVE, CAPPED_WHEN, COMPUTABLE_MAX, DEFAULT_PARAMS, META_KEYS, MODES,
                                          OPENCV_3WAY_UNIQUENESS_MAX, SUM_AT_LEAST, accepted_range,
                                          OPENCV_COST_MAX, OPENCV_PRE_FILTER_CAP_FLOOR, SECTIONS, SPEC_BY_KEY, SPECS,
                                          ComputeParams, SGBMParams, Spec, StereoParams, WLSParams, params_from_dict,
                                          params_table_markdown)

__all__ = ["ABOVE", "CAPPED_WHEN", "COMPUTABLE_MAX", "SUM_AT_LEAST", "accepted_range", "DEFAULT_PARAMS", "META_KEYS", "MODES", "OPENCV_3WAY_UNIQUENESS_MAX", "OPENCV_COST_MAX",
           "OPENCV_PRE_FILTER_CAP_FLOOR", "SECTIONS", "SPECS", "SPEC_BY_KEY", "ComputeParams", "SGBMParams", "Spec",
           "StereoParams", "WLSParams", "check_computable", "check_image_size", "disparity_search_range",
           "dump_params", "load_params", "params_from_dict", "params_table_markdown", "read_provenance",
           "save_params"]
