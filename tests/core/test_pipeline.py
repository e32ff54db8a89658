"""The declared disparity pipelines: what flies and the tuner's faithful mode are lists of stages."""

import numpy as np
import pytest

from uav_depth.core.disparity import FAITHFUL, FLIGHT, MEASURED, DisparityPipeline, Step, flight_pipeline
from uav_depth.core.params import DEFAULT_PARAMS


def test_the_declared_pipelines():
    assert FLIGHT == (Step.MATCH, Step.NEAR, Step.FINE)
    assert FAITHFUL == (Step.MATCH, Step.WLS) and MEASURED == (Step.MATCH,)
    assert flight_pipeline(DEFAULT_PARAMS).steps == FLIGHT and DisparityPipeline(DEFAULT_PARAMS).steps == FAITHFUL


@pytest.mark.parametrize("steps", [(), (Step.NEAR,), (Step.MATCH, Step.MATCH), (Step.MATCH, Step.FINE, Step.NEAR)],
                         ids=["empty", "no-match", "twice", "out-of-order"])
def test_a_pipeline_must_start_with_the_match_and_keep_the_order(steps):
    with pytest.raises(ValueError, match="must start with MATCH"):
        DisparityPipeline(DEFAULT_PARAMS, steps)


def test_each_declared_stage_adds_its_result():
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (120, 400), dtype=np.uint8)
    left, right = np.ascontiguousarray(base[:, 10:330]), np.ascontiguousarray(base[:, :320])
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32, "compute.scale": 0.5,
                                       "compute.fine_disparities": 16})
    flight = flight_pipeline(params).run(left, right)
    assert flight.near is not None and flight.fine is not None and "wls" not in flight.timings_ms
    assert "near" in flight.timings_ms
    faithful = DisparityPipeline(params, FAITHFUL).run(left, right)
    assert faithful.near is None and faithful.fine is None and "wls" in faithful.timings_ms
    measured = DisparityPipeline(params, MEASURED).run(left, right)
    assert measured.near is None and measured.fine is None and "wls" not in measured.timings_ms
    np.testing.assert_array_equal(measured.measured, flight.measured)
