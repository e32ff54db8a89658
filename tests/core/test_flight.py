"""What flies, declared once: the shipped flight files are the recommended settings."""

from pathlib import Path

from uav_depth.core.params import load_params
from uav_depth.core.params.flight import FLIGHT_640X360_FILE, FLIGHT_FILE, flight_params, flight_working_distance_m

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_the_package_reads_the_files_deploy_installs():
    # One copy of the values: in a checkout the package's files are deploy/'s (a wheel carries a copy of them,
    # tests/test_packaging.py).
    assert FLIGHT_FILE.read_bytes() == (DEPLOY / "params-flight.yaml").read_bytes()
    assert FLIGHT_640X360_FILE.read_bytes() == (DEPLOY / "params-flight-640x360.yaml").read_bytes()
    assert FLIGHT_FILE.resolve() == (DEPLOY / "params-flight.yaml").resolve()


def test_flight_params_is_the_shipped_file_with_the_search_a_camera_needs():
    flight = load_params(DEPLOY / "params-flight.yaml")
    assert flight_params() == flight
    assert flight.sgbm.mode == "sgbm_3way" and flight.compute.scale == 0.5 and flight.compute.grey
    # The 640x360 file is the same settings at focal 350 px: only the search differs.
    small = load_params(DEPLOY / "params-flight-640x360.yaml")
    assert flight_params(focal_px=350.0, baseline_m=0.063) == small
    assert small.replace(**{"sgbm.num_disparities": flight.sgbm.num_disparities}) == flight
    # Another camera: the search covers the working distance's near end at the file's scale.
    near_m, far_m = flight_working_distance_m()
    assert (near_m, far_m) == (0.3, 3.0)
    wide = flight_params(focal_px=1400.0, baseline_m=0.063)
    assert (wide.sgbm.num_disparities - 1 + wide.sgbm.min_disparity) / wide.compute.scale >= 1400.0 * 0.063 / near_m
    assert wide.replace(**{"sgbm.num_disparities": flight.sgbm.num_disparities}) == flight
