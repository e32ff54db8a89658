import subprocess
import sys

import pytest
import yaml

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.params import (DEFAULT_PARAMS, OPENCV_COST_MAX, SPECS, check_image_size, dump_params,
                                     load_params, params_from_dict,
                                     read_provenance, save_params)


def test_defaults_are_opencv_sample_values():
    sg = DEFAULT_PARAMS.sgbm
    bs = sg.block_size
    assert (sg.p1, sg.p2) == (8 * 3 * bs * bs, 32 * 3 * bs * bs)
    assert (sg.disp12_max_diff, sg.uniqueness_ratio, sg.speckle_window_size, sg.speckle_range) == (1, 10, 100, 32)
    assert (DEFAULT_PARAMS.wls.lambda_, DEFAULT_PARAMS.wls.sigma_color) == (8000.0, 1.5)


def test_round_trip_with_provenance(tmp_path):
    params = DEFAULT_PARAMS.replace(**{"sgbm.p1": 100, "sgbm.p2": 5000, "wls.lambda": 1234.5})
    path = save_params(params, tmp_path / "p.yaml", provenance={"metric": "mse", "seed": 3})
    assert load_params(path) == params
    assert read_provenance(path) == {"metric": "mse", "seed": 3}
    assert not [p for p in tmp_path.iterdir() if p.name != "p.yaml"], "temp file left behind"


def test_every_key_documented_with_default_that_validates():
    assert params_from_dict({}) == DEFAULT_PARAMS
    for spec in SPECS:
        assert spec.check(spec.default) == spec.default


def test_hash_changes_with_values():
    assert DEFAULT_PARAMS.hash() != DEFAULT_PARAMS.replace(**{"sgbm.uniqueness_ratio": 11}).hash()


BAD = [
    ("mult16", {"sgbm": {"num_disparities": 40}}, "sgbm.num_disparities must be a positive multiple of 16, but got 40"),
    ("odd", {"sgbm": {"block_size": 4}}, "sgbm.block_size must be odd, but got 4"),
    ("range", {"sgbm": {"uniqueness_ratio": 101}}, "sgbm.uniqueness_ratio must be between 0 and 100, but got 101"),
    ("p2-gt-p1", {"sgbm": {"p1": 500, "p2": 400}}, "sgbm.p2 must be greater than sgbm.p1 (500), but got 400"),
    ("search-below-zero", {"sgbm": {"min_disparity": -16, "num_disparities": 16}},
     "sgbm.num_disparities must reach positive disparities: with sgbm.min_disparity -16 the largest disparity "
     "searched (min_disparity + num_disparities - 1) must be at least 1"),
    ("3way-uniqueness-100", {"sgbm": {"mode": "sgbm_3way", "uniqueness_ratio": 100}},
     "sgbm.uniqueness_ratio must be at most 99 with sgbm.mode sgbm_3way (OpenCV's 3-way matcher divides by"),
    ("mode", {"sgbm": {"mode": "fast"}}, "sgbm.mode must be one of sgbm, sgbm_3way, hh, hh4, but got 'fast'"),
    ("type", {"sgbm": {"p1": "big"}}, "sgbm.p1 must be a number (int), but got 'big'"),
    ("float-int", {"sgbm": {"p1": 10.5}}, "sgbm.p1 must be an integer, but got 10.5"),
    ("bool", {"wls": {"enabled": "yes"}}, "wls.enabled must be true or false, but got 'yes'"),
    ("unknown-key", {"sgbm": {"p3": 1}}, "sgbm.p3 is not a known key"),
    ("unknown-section", {"sgmb": {}}, "sgmb is not a known section"),
    ("sigma-zero", {"wls": {"sigma_color": 0}}, "wls.sigma_color must be greater than 0, but got 0.0"),
    ("nan", {"wls": {"lambda": float("nan")}}, "wls.lambda must be a finite number"),
    ("section-not-map", {"sgbm": 5}, "sgbm must be a mapping, but got 5"),
    ("p2-over-16-bit", {"sgbm": {"p2": 32768}}, "sgbm.p2 must be at most 32767 (OpenCV's SGBM keeps costs in 16-bit"),
    ("p1-over-16-bit", {"sgbm": {"p1": 40000, "p2": 50000}}, "sgbm.p1 must be at most 32767"),
    ("empty-mapping", {}, "(file) must set at least one section (sgbm, wls, compute); an empty file is not taken"),
    ("only-provenance", {"provenance": {"by": "hand"}}, "must set at least one section"),
]


@pytest.mark.parametrize("data,message", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_values_name_key_rule_value(tmp_path, data, message):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_params(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("text,message", [("sgbm: [1, 2\n", "not valid YAML at line"),
                                          ("- 1\n- 2\n", "must be a mapping of sections")],
                         ids=["broken-yaml", "list"])
def test_bad_files(tmp_path, text, message):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    with pytest.raises((ConfigError, FileFormatError), match=message):
        load_params(path)


@pytest.mark.parametrize("text", ["", "\n", "# tuned later\n", "---\n"], ids=["empty", "newline", "comment", "document-marker"])
def test_an_empty_file_is_an_error_not_the_defaults(tmp_path, text):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"must set at least one section .* not taken as the defaults"):
        load_params(path)


def test_the_largest_penalties_opencv_can_hold_load(tmp_path):
    path = save_params(DEFAULT_PARAMS.replace(**{"sgbm.p1": OPENCV_COST_MAX - 1, "sgbm.p2": OPENCV_COST_MAX}),
                       tmp_path / "p.yaml")
    assert load_params(path).sgbm.p2 == OPENCV_COST_MAX


@pytest.mark.parametrize("changes,width,height,message", [
    ({"sgbm.num_disparities": 640}, 640, 360, r"sgbm\.num_disparities must leave columns to match: .* below the "
                                               r"matched image width 640 px"),
    ({"sgbm.num_disparities": 320, "compute.scale": 0.5}, 640, 360, r"matched image width 320 px \(640 px x "
                                                                   r"compute.scale 0.5\)"),
    ({"sgbm.num_disparities": 304, "sgbm.min_disparity": 1, "sgbm.block_size": 31}, 320, 240, r"sgbm\.num_disparities must leave columns"),
    ({"sgbm.block_size": 31, "sgbm.num_disparities": 16}, 40, 24, r"sgbm\.block_size must fit the matched image "
                                                                   r"\(40x24 px\)"),
], ids=["search-as-wide-as-image", "search-wider-than-scaled-image", "search-plus-half-block", "block-taller"])
def test_parameters_that_cannot_match_at_an_image_size_are_refused(changes, width, height, message):
    with pytest.raises(ConfigError, match=message):
        check_image_size(DEFAULT_PARAMS.replace(**changes), width, height, "p.yaml")


def test_a_search_range_that_fits_passes_the_image_size_check():
    check_image_size(DEFAULT_PARAMS, 1280, 720)
    check_image_size(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 288}), 320, 240)   # 320 - 288 > 5 // 2


def test_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="parameter file not found"):
        load_params(tmp_path / "nope.yaml")


def test_save_refuses_nothing_invalid_and_keeps_old_file(tmp_path):
    path = save_params(DEFAULT_PARAMS, tmp_path / "p.yaml")
    before = path.read_text()
    with pytest.raises(ConfigError):
        DEFAULT_PARAMS.replace(**{"sgbm.block_size": 6})
    assert path.read_text() == before
    assert dump_params(DEFAULT_PARAMS) == before


# -- compute.* (speed levers that change the disparity, so they live in the file) ---------------------------------


def test_compute_defaults_are_the_full_frame_baseline():
    cp = DEFAULT_PARAMS.compute
    assert cp.is_baseline and cp.roi == (0.0, 0.0, 1.0, 1.0) and cp.scale == 1.0 and cp.grey is False
    assert cp.roi_pixels(1280, 720) == (0, 0, 1280, 720)
    assert DEFAULT_PARAMS.to_dict()["compute"] == {"roi": [0.0, 0.0, 1.0, 1.0], "scale": 1.0, "grey": False,
                                                   "wls_at": "input", "fine_disparities": 0}


def test_compute_keys_round_trip_and_region_is_written_on_one_line(tmp_path):
    params = DEFAULT_PARAMS.replace(**{"compute.roi": [0.25, 0.3, 0.75, 0.7], "compute.scale": 0.5,
                                       "compute.grey": True})
    assert not params.compute.is_baseline
    path = save_params(params, tmp_path / "p.yaml")
    assert "roi: [0.25, 0.3, 0.75, 0.7]" in path.read_text()
    assert load_params(path) == params
    assert params.hash() != DEFAULT_PARAMS.hash()


def test_a_file_without_compute_section_loads_as_baseline(tmp_path):
    path = tmp_path / "old.yaml"
    path.write_text("sgbm:\n  p1: 100\n  p2: 400\nwls:\n  lambda: 100.0\n")
    assert load_params(path).compute == DEFAULT_PARAMS.compute


@pytest.mark.parametrize("width,height,roi,box", [
    (1280, 720, (0.33, 0.33, 0.67, 0.67), (422, 238, 858, 482)),
    (320, 240, (0.0, 0.5, 0.25, 1.0), (0, 120, 80, 240)),
    (100, 100, (0.5, 0.5, 0.501, 0.502), (50, 50, 51, 51)),      # never empty
], ids=["centre", "corner", "tiny"])
def test_roi_pixels(width, height, roi, box):
    params = DEFAULT_PARAMS.replace(**{"compute.roi": list(roi)})
    assert params.compute.roi_pixels(width, height) == box


BAD_COMPUTE = [
    ("roi-not-list", {"compute": {"roi": 0.5}}, "compute.roi must be a list of 4 numbers [left, top, right, bottom]"),
    ("roi-three", {"compute": {"roi": [0, 0, 1]}}, "compute.roi must be a list of 4 numbers"),
    ("roi-text", {"compute": {"roi": [0, 0, "1", 1]}}, "compute.roi must be a list of 4 numbers"),
    ("roi-range", {"compute": {"roi": [0, 0, 1.5, 1]}}, "compute.roi must have every number between 0 and 1"),
    ("roi-order", {"compute": {"roi": [0.6, 0, 0.4, 1]}}, "compute.roi must have left < right and top < bottom, "
                                                          "but got [0.6, 0, 0.4, 1]"),
    ("scale-range", {"compute": {"scale": 0.1}}, "compute.scale must be between 0.125 and 1, but got 0.1"),
    ("scale-up", {"compute": {"scale": 2}}, "compute.scale must be between 0.125 and 1, but got 2.0"),
    ("grey-bool", {"compute": {"grey": 1}}, "compute.grey must be true or false, but got 1"),
    ("wls-at", {"compute": {"wls_at": "half"}}, "compute.wls_at must be one of input, matched, but got 'half'"),
    ("unknown", {"compute": {"threads": 2}}, "compute.threads is not a known key"),
]


@pytest.mark.parametrize("data,message", [b[1:] for b in BAD_COMPUTE], ids=[b[0] for b in BAD_COMPUTE])
def test_bad_compute_values_name_key_rule_value(tmp_path, data, message):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_params(path)
    assert message in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)


def test_disparity_search_range_from_working_distance():
    from uav_depth.core.params import disparity_search_range

    # ZED Mini-like 1280x720: f*B = 44.1 px*m; 0.3 m is d = 147 px, 3 m is 14.7 px.
    assert disparity_search_range(700.0, 0.063, 0.3) == (0, 160)
    assert disparity_search_range(700.0, 0.063, 0.3, scale=0.5) == (0, 80)
    assert disparity_search_range(700.0, 0.063, 0.3, 3.0, scale=0.5) == (7, 80)
    assert disparity_search_range(700.0, 0.063, 0.5) == (0, 96)
    with pytest.raises(ConfigError, match="near_m must be a positive distance"):
        disparity_search_range(700.0, 0.063, 0.0)
    with pytest.raises(ConfigError, match="far_m must be greater than near_m"):
        disparity_search_range(700.0, 0.063, 1.0, 0.5)
    with pytest.raises(ConfigError, match="sgbm.num_disparities must be between 16 and 1024"):
        disparity_search_range(700.0, 0.063, 0.01)


_MATCH_AT_BOUND = """
import sys, numpy as np
from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.params import DEFAULT_PARAMS, SPEC_BY_KEY, params_from_dict, MODES
for mode in MODES:
    d = DEFAULT_PARAMS.to_dict()
    d["sgbm"].update(mode=mode, num_disparities=32)
    for u in range(int(SPEC_BY_KEY["sgbm.uniqueness_ratio"].hi), 90, -1):
        d["sgbm"]["uniqueness_ratio"] = u
        try:
            p = params_from_dict(d)
        except Exception:
            continue          # the schema refuses it: fine, it never reaches OpenCV
        rng = np.random.default_rng(0)
        base = rng.integers(0, 256, (48, 140), dtype=np.uint8)
        flight_pipeline(p).run(np.ascontiguousarray(base[:, :128]), np.ascontiguousarray(base[:, 6:134]))
        print(mode, u, flush=True)
        break
"""


def test_every_mode_runs_at_the_highest_uniqueness_the_schema_accepts():
    # OpenCV's 3-way matcher dies of SIGFPE at uniqueness 100; the schema must refuse what kills the process.
    out = subprocess.run([sys.executable, "-c", _MATCH_AT_BOUND], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, f"exit {out.returncode}: {out.stderr[-2000:]}"
    assert out.stdout.split() == ["sgbm", "100", "sgbm_3way", "99", "hh", "100", "hh4", "100"]


def test_the_lowest_search_the_schema_accepts_builds_the_flight_pipeline():
    # The schema fuzz (bench/params_fuzz.py) found min_disparity -16 with num_disparities 16: the flight
    # pipeline's near pass divided by the largest disparity searched, 0 (ZeroDivisionError, a traceback).
    from uav_depth.core.disparity import flight_pipeline

    for low, num in ((-14, 16), (-256, 272), (0, 16)):
        flight_pipeline(params_from_dict({"sgbm": {"min_disparity": low, "num_disparities": num}}))
    for low, num in ((-15, 16), (-16, 16), (-256, 256), (-100, 32)):
        with pytest.raises(ConfigError, match="must reach positive disparities"):
            params_from_dict({"sgbm": {"min_disparity": low, "num_disparities": num}})
