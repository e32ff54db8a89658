"""The run config: one validated file, environment overrides, explicit arguments win."""

import logging
from pathlib import Path

import pytest

from uav_depth.daemon.config import (MavlinkConfig, RangingConfig, env_keys, load_run_config, load_section,
                                     reference_markdown, run_config_from_dict, SECTION_CLASSES)
from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.cli.sources import SOURCES
from uav_depth.daemon.sources import source_keys

ROOT = Path(__file__).resolve().parents[2]
SYNTH = {"kind": "synthetic", "scene": {"width": 320, "height": 240, "focal_px": 200.0}}


def write(tmp_path, text, name="run.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_defaults_are_the_documented_ones():
    cfg = run_config_from_dict({"source": SYNTH}, sources=SOURCES)
    assert cfg.source_kind == "synthetic"
    assert cfg.params_file is None and cfg.calibration is None and cfg.logging.dir is None
    assert cfg.mavlink == MavlinkConfig()
    assert (cfg.mavlink.url, cfg.mavlink.rate_hz, cfg.mavlink.system_id, cfg.mavlink.component_id) == \
        ("udpout:127.0.0.1:14550", 20.0, 1, 191)
    assert cfg.ranging == RangingConfig() and cfg.ranging.max_age_ms < 500
    assert cfg.source.scene.width == 320 and cfg.source.fps == 15.0


@pytest.mark.parametrize("example", sorted(p.name for p in (ROOT / "deploy" / "examples").glob("*.yaml")))
def test_deploy_examples_validate(example):
    cfg = load_run_config(ROOT / "deploy" / "examples" / example, environ={}, sources=SOURCES)
    assert cfg.source_kind in SOURCES


def test_precedence_argument_over_environment_over_file(tmp_path):
    path = write(tmp_path, "source: {kind: synthetic}\nmavlink: {rate_hz: 12, url: 'udpout:127.0.0.1:1'}\n")
    assert load_run_config(path, environ={}, sources=SOURCES).mavlink.rate_hz == 12
    env = {"UAV_DEPTH_MAVLINK_RATE_HZ": "25", "UAV_DEPTH_MAVLINK_URL": "udpin:0.0.0.0:14560"}
    cfg = load_run_config(path, environ=env, sources=SOURCES)
    assert cfg.mavlink.rate_hz == 25 and cfg.mavlink.url == "udpin:0.0.0.0:14560"
    cfg = load_run_config(path, overrides={"mavlink.rate_hz": 30}, environ=env, sources=SOURCES)
    assert cfg.mavlink.rate_hz == 30 and cfg.mavlink.url == "udpin:0.0.0.0:14560"


def test_one_section_resolves_as_run_would_without_a_frame_source(tmp_path):
    # What the tuner ranges with: the ranging section run would fly, also with no config file at all (then only
    # the UAV_DEPTH_RANGING_* variables and the defaults) and from a file without a source.
    assert load_section("ranging", None, environ={}, sources=SOURCES) == \
        (RangingConfig(), "the default ranging settings (no config file)")
    env = {"UAV_DEPTH_RANGING_MAX_DISTANCE_M": "4.5", "UAV_DEPTH_MAVLINK_RATE_HZ": "25"}
    ranging, where = load_section("ranging", None, environ=env, sources=SOURCES)
    assert ranging.max_distance_m == 4.5 and where == "environment UAV_DEPTH_RANGING_MAX_DISTANCE_M"
    path = write(tmp_path, "ranging: {max_distance_m: 3.0, min_quality: 40}\n")
    ranging, where = load_section("ranging", path, environ=env, sources=SOURCES)
    assert (ranging.max_distance_m, ranging.min_quality) == (4.5, 40)
    assert where == f"the ranging settings of {path} and environment UAV_DEPTH_RANGING_MAX_DISTANCE_M"
    ranging, _ = load_section("ranging", None, environ={"UAV_DEPTH_CONFIG": str(path)}, sources=SOURCES)
    assert ranging.max_distance_m == 3.0
    with pytest.raises(ConfigError, match="ranging.max_distance_m"):
        load_section("ranging", None, environ={"UAV_DEPTH_RANGING_MAX_DISTANCE_M": "-1"}, sources=SOURCES)
    # whole_file: the file run would fly is validated as run would: without a source, run refuses it.
    with pytest.raises(ConfigError, match="source"):
        load_section("ranging", path, environ={}, sources=SOURCES, whole_file=True)
    whole = write(tmp_path, "source: {kind: synthetic}\nranging: {max_distance_m: 3.0}\n", "whole.yaml")
    assert load_section("ranging", whole, environ=env, sources=SOURCES, whole_file=True)[0].max_distance_m == 4.5


def test_config_file_from_environment_and_relative_paths(tmp_path):
    (tmp_path / "calib.yaml").write_text("focal_px: 200.0\nbaseline_m: 0.06\nwidth: 320\nheight: 240\n")
    path = write(tmp_path, "source: {kind: replay, path: logs/s1}\ncalibration: calib.yaml\n"
                           "params_file: p.yaml\nlogging: {dir: logs}\n")
    cfg = load_run_config(None, environ={"UAV_DEPTH_CONFIG": str(path)}, sources=SOURCES)
    assert cfg.source.path == tmp_path / "logs" / "s1"
    assert cfg.params_file == tmp_path / "p.yaml" and cfg.logging.dir == tmp_path / "logs"
    assert cfg.calibration.focal_px == 200.0 and cfg.calibration.baseline_m == 0.06


def test_every_settable_key_has_an_environment_name():
    names = env_keys(SOURCES)
    assert names["UAV_DEPTH_PARAMS_FILE"] == "params_file"
    assert names["UAV_DEPTH_RANGING_MAX_AGE_MS"] == "ranging.max_age_ms"
    assert names["UAV_DEPTH_SOURCE_KIND"] == "source.kind"
    for section, cls in SECTION_CLASSES.items():
        for key in cls.KEYS:
            assert f"UAV_DEPTH_{section.upper()}_{key.name.upper()}" in names


def test_unknown_environment_variable_is_logged_not_fatal(tmp_path, caplog):
    path = write(tmp_path, "source: {kind: synthetic}\n")
    with caplog.at_level(logging.WARNING, logger="uav_depth.config"):
        load_run_config(path, environ={"UAV_DEPTH_MAVLNK_URL": "x"}, sources=SOURCES)
    assert "UAV_DEPTH_MAVLNK_URL" in caplog.text


@pytest.mark.parametrize("data,message", [
    ({"source": SYNTH, "mavlink": {"rate_hz": 500}}, "mavlink.rate_hz must be between 2 and 200, but got 500"),
    ({"source": SYNTH, "ranging": {"max_age_ms": 500}}, "ranging.max_age_ms must be at least 1 and below 500"),
    ({"source": SYNTH, "ranging": {"roi": [10, 10, 5, 20]}}, "ranging.roi must satisfy 0 <= x0 < x1"),
    ({"source": SYNTH, "ranging": {"roi": [1, 2, 3]}}, "ranging.roi must be four integers"),
    ({"source": SYNTH, "ranging": {"max_age": 100}}, "ranging.max_age is not a known key"),
    ({"source": SYNTH, "mavlnk": {}}, "mavlnk is not a known section"),
    ({"source": {"kind": "kinect"}}, "source.kind must be one of synthetic, replay, uvc, oak, but got 'kinect'"),
    ({}, "source is required"),
    ({"source": SYNTH, "mavlink": {"component_id": 1}}, "mavlink.component_id must not be 1 when system_id is 1"),
    ({"source": SYNTH, "mavlink": {"url": "udp-out:1.2.3.4"}}, "mavlink.url must be a pymavlink connection string"),
    ({"source": SYNTH, "mavlink": {"orientation": "sideways"}}, "mavlink.orientation must be forward, back"),
    ({"source": SYNTH, "mavlink": {"sensor_type": "lidar"}}, "mavlink.sensor_type must be one of laser"),
    ({"source": {**SYNTH, "scene": {"widht": 3}}}, "source.scene.widht is not a known scene key"),
    ({"source": {**SYNTH, "approach_speed_mps": 0.5, "stop_distance_m": 2.0}},
     "source.stop_distance_m must be below scene.branch_distance_m"),
    ({"source": {"kind": "replay"}}, "source.path is required"),
    ({"source": {"kind": "uvc", "device": 0, "right_device": 0}}, "source.right_device must differ"),
    ({"source": {"kind": "uvc", "device": -1}}, "source.device must be a V4L2 index"),
    ({"source": SYNTH, "logging": {"every_n": -1}}, "logging.every_n must be between 0 and"),
    ({"source": SYNTH, "calibration": {"focal_px": 200}}, "calibration.baseline_m is required"),
], ids=["rate", "max-age", "roi-order", "roi-shape", "unknown-key", "unknown-section", "kind", "no-source",
        "loopback-ids", "url", "orientation", "sensor-type", "scene-key", "stop-distance", "replay-path",
        "same-devices", "device", "every-n", "calibration"])
def test_bad_config_names_key_rule_and_value(data, message):
    with pytest.raises(ConfigError) as info:
        run_config_from_dict(data, source="run.yaml", sources=SOURCES)
    assert message in str(info.value)
    assert str(info.value).count("\n") == 0


def test_errors_say_where_the_value_came_from(tmp_path):
    path = write(tmp_path, "source: {kind: synthetic}\n")
    with pytest.raises(ConfigError, match=r"^environment UAV_DEPTH_MAVLINK_RATE_HZ: mavlink.rate_hz must be a number"):
        load_run_config(path, environ={"UAV_DEPTH_MAVLINK_RATE_HZ": "fast"}, sources=SOURCES)
    with pytest.raises(ConfigError, match=r"^command line: ranging.max_age_ms must be at least 1 and below 500"):
        load_run_config(path, overrides={"ranging.max_age_ms": 900}, environ={}, sources=SOURCES)
    bad = write(tmp_path, "source: {kind: synthetic}\nmavlink: {rate_hz: 1}\n", "bad.yaml")
    with pytest.raises(ConfigError, match=r"bad.yaml: mavlink.rate_hz must be between 2 and 200, but got 1"):
        load_run_config(bad, environ={}, sources=SOURCES)


def test_invalid_yaml_and_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="config is not valid YAML at line 3"):
        load_run_config(write(tmp_path, "source:\n  kind: [synthetic\n"), environ={}, sources=SOURCES)
    with pytest.raises(ConfigError, match="--config must name an existing file"):
        load_run_config(tmp_path / "nope.yaml", environ={}, sources=SOURCES)


@pytest.mark.parametrize("name,code", [("forward", 0), ("down", 25), ("up", 24), ("back", 4), ("ROLL_180", 8),
                                       (3, 3)])
def test_orientation_names(name, code):
    from uav_depth.daemon.link.vocabulary import orientation_code

    assert orientation_code(name) == code
    assert run_config_from_dict({"source": SYNTH, "mavlink": {"orientation": name}}, sources=SOURCES).mavlink.orientation == name


def test_reference_documents_every_key():
    table = reference_markdown(SOURCES)
    for section, cls in SECTION_CLASSES.items():
        for key in cls.KEYS:
            assert f"`{section}.{key.name}`" in table
    for kind in SOURCES:
        for key in source_keys(kind, SOURCES):
            assert f"`source.{key.name}` ({kind})" in table


def test_a_setting_given_as_text_is_read_without_anchors_or_aliases():
    from uav_depth.daemon.config import parse_value

    assert parse_value("25") == 25 and parse_value("[1, 2]") == [1, 2] and parse_value("{a: 1}") == {"a": 1}
    bomb = "[&a [x, x, x, x, x, x, x, x, x], [*a, *a, *a, *a, *a, *a, *a, *a, *a]]"
    assert parse_value(bomb) == bomb     # stays text: the key's own rule names it, nothing is expanded
