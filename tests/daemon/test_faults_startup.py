"""Faults at start-up against the real daemon process: one line and exit 78, and run --check refuses the same.

Each fault ends in one line and the documented exit code (78 for anything in a
config, parameter or key file), or, while flying, in one log line with the last
good parameters kept: never a traceback, a restart loop or a silent change.
See docs/operations.md.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from uav_depth.cli.exit_codes import EXIT_CONFIG, EXIT_UNAVAILABLE

from daemon_process import (GOOD, IS_ROOT, KEY_HEX, OVERSIZE_PARAMS, PARAMS_64, THREE_WAY_100, _params_with, alias_bomb,
                            as_nobody, config, one_error_line, run_daemon)


# -- start-up: one line, exit 78 ---------------------------------------------------------------------

def _setup_params(data: bytes):
    def setup(d: Path, port: int):
        (d / "params.yaml").write_bytes(data)
        return config(port, d / "params.yaml")
    return setup


def _setup_config_bytes(data: bytes):
    def setup(d: Path, port: int):
        return data
    return setup


def _setup_key_directory(d: Path, port: int):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "keydir").mkdir(mode=0o700)
    return config(port, d / "params.yaml", mavlink={"signing_key_file": str(d / "keydir")})


def _setup_key_unreadable(d: Path, port: int):
    # Root-owned 0600 and the daemon runs as nobody (as root); 0000 when the tests are not root.
    (d / "params.yaml").write_bytes(GOOD)
    key = d / "key.txt"
    key.write_bytes(KEY_HEX)
    os.chmod(key, 0o600 if IS_ROOT else 0o000)
    return config(port, d / "params.yaml", mavlink={"signing_key_file": str(key)})


def _setup_logdir_under_a_file(d: Path, port: int):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "plain-file").write_text("x")
    return config(port, d / "params.yaml", logging={"dir": str(d / "plain-file" / "logs")})


def _setup_logdir_not_writable(d: Path, port: int):
    # Like /var/lib/uav-depth without permission: it exists, the service user may not write in it.
    (d / "params.yaml").write_bytes(GOOD)
    logs = d / "logs"
    logs.mkdir()
    os.chmod(logs, 0o755 if IS_ROOT else 0o555)
    return config(port, d / "params.yaml", logging={"dir": str(logs)})


DUPLICATE_CONFIG = b"""source:
  kind: synthetic
mavlink:
  rate_hz: 20
mavlink:
  rate_hz: 50
"""

STARTUP_FAULTS = [
    pytest.param(_setup_params(THREE_WAY_100), r"sgbm\.uniqueness_ratio must be at most 99 with sgbm\.mode sgbm_3way",
                 id="params-3way-uniqueness-100"),
    pytest.param(_setup_params(alias_bomb()), r"parameter file uses a YAML anchor \('l0'\) at line 1",
                 id="params-alias-bomb"),
    pytest.param(_setup_params(OVERSIZE_PARAMS), r"parameter file is \d+ bytes, more than the 64 KiB",
                 id="params-over-the-size-cap"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic\n  scene: {width: 100000, height: 100000}\n"),
                 r"source\.scene\.width must be between 32 and 4096, but got 100000", id="scene-100000-px"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic\n" + alias_bomb()),
                 r"config uses a YAML anchor \('l0'\) at line 3", id="config-alias-bomb"),
    pytest.param(_setup_params(b"sgbm:\n  p1: 600  # caf\xe9\n"), r"parameter file is not UTF-8 text \(byte 0xe9",
                 id="params-not-utf8"),
    pytest.param(_setup_params(b""), r"must set at least one section \(sgbm, wls, compute\); an empty file is not",
                 id="params-empty"),
    pytest.param(_setup_params(b"# tuned later\n"), r"must set at least one section", id="params-only-comments"),
    pytest.param(_setup_params(b"sgbm:\n  p1: 600\n  p2: 2400\n  p1: 900\n"),
                 r"sgbm\.p1 is given twice \(line 2 and line 4\)", id="params-duplicate-key"),
    pytest.param(_setup_params(_params_with(**{"sgbm.p2": 40000})), r"sgbm\.p2 must be at most 32767",
                 id="params-p2-over-16-bit-costs"),
    pytest.param(_setup_params(_params_with(**{"sgbm.p1": 33000, "sgbm.p2": 34000})), r"sgbm\.p1 must be at most 32767",
                 id="params-p1-over-16-bit-costs"),
    pytest.param(_setup_params(_params_with(**{"sgbm.num_disparities": 320})),
                 r"sgbm\.num_disparities must leave columns to match.*matched image width 320 px",
                 id="params-search-range-wider-than-image"),
    pytest.param(_setup_params(_params_with(**{"sgbm.num_disparities": 224, "sgbm.block_size": 31})),
                 r"\(parameters\) must measure a test render .*they measured nothing",
                 id="params-search-range-hides-the-roi"),
    pytest.param(_setup_config_bytes(b"\x7fELF\x02\x01\x01\x00\x00\x00binary"), r"config is a binary file",
                 id="config-binary"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic  # \xff\n"), r"config is not UTF-8 text",
                 id="config-not-utf8"),
    pytest.param(_setup_config_bytes(DUPLICATE_CONFIG), r"mavlink is given twice \(line 3 and line 5\)",
                 id="config-duplicate-key"),
    pytest.param(_setup_key_directory, r"mavlink\.signing_key_file must name a file, not a directory",
                 id="key-is-a-directory"),
    pytest.param(_setup_key_unreadable, r"mavlink\.signing_key_file must be readable by this user .*Permission denied",
                 id="key-unreadable-by-the-service-user"),
    pytest.param(_setup_logdir_under_a_file, r"logging\.dir must be a directory this user .* can create and write",
                 id="logdir-cannot-be-created"),
    pytest.param(_setup_logdir_not_writable, r"logging\.dir must be a directory this user .* can create and write",
                 id="logdir-not-writable"),
]


#: The faults only an unprivileged user meets (root reads and writes whatever the modes say).
AS_NOBODY = (_setup_key_unreadable, _setup_logdir_not_writable)


@pytest.mark.parametrize("setup,message", STARTUP_FAULTS)
def test_a_fault_in_a_file_is_one_line_and_exit_78_for_run_and_run_check(shared_dir, port, setup, message):
    user = as_nobody() if setup in AS_NOBODY else None
    cfg = setup(shared_dir, port)
    for extra in ((), ("--check",)):
        daemon = run_daemon(shared_dir, cfg, *extra, user=user)
        try:
            code = daemon.wait(120)
        finally:
            daemon.kill()
        err = daemon.stderr()
        line = one_error_line(err, "run --check" if extra else "run")
        assert code == EXIT_CONFIG, err[-3000:]
        assert re.search(message, line), line


# -- run --check refuses what run refuses -------------------------------------------------------------

def _check_params_p2_below_p1(d, port):
    (d / "params.yaml").write_bytes(b"sgbm:\n  p1: 900\n  p2: 800\n")
    return config(port, d / "params.yaml"), EXIT_CONFIG, r"sgbm\.p2 must be greater than sgbm\.p1 \(900\)"


def _check_params_not_yaml(d, port):
    (d / "params.yaml").write_bytes(b"sgbm: [1, 2\n")
    return config(port, d / "params.yaml"), EXIT_CONFIG, r"parameter file is not valid YAML at line 2"


def _check_key_mode_0644(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "key.txt").write_bytes(KEY_HEX)
    os.chmod(d / "key.txt", 0o644)
    return (config(port, d / "params.yaml", mavlink={"signing_key_file": str(d / "key.txt")}), EXIT_CONFIG,
            r"signing_key_file must not be accessible by group or others \(chmod 600\)")


def _check_replay_path_missing(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    return (config(port, d / "params.yaml", source={"kind": "replay", "path": str(d / "no-such-log")}),
            EXIT_UNAVAILABLE, r"replay: .*no-such-log")


def _check_zed_calibration_missing(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    return (config(port, d / "params.yaml", source={"kind": "uvc", "device": "/dev/video97",
                                                     "zed_calibration": str(d / "SN000.conf")}),
            EXIT_CONFIG, r"SN000\.conf: ZED calibration file not found")


@pytest.mark.parametrize("setup", [
    pytest.param(_check_params_p2_below_p1, id="params-p2-below-p1"),
    pytest.param(_check_params_not_yaml, id="params-malformed"),
    pytest.param(_check_key_mode_0644, id="key-mode-0644"),
    pytest.param(_check_replay_path_missing, id="replay-path-missing"),
    pytest.param(_check_zed_calibration_missing, id="zed-calibration-missing"),
])
def test_run_check_refuses_what_run_refuses_with_the_same_line_and_code(tmp_path, port, setup):
    cfg, code, message = setup(tmp_path, port)
    lines = {}
    for extra in (("--check",), ()):
        daemon = run_daemon(tmp_path, cfg, *extra)
        try:
            got = daemon.wait(120)
        finally:
            daemon.kill()
        line = one_error_line(daemon.stderr(), "run --check" if extra else "run")
        assert got == code and re.search(message, line), line
        lines[extra] = line.split(": error: ", 1)[1]
    assert lines[("--check",)] == lines[()]


def test_run_check_passes_a_good_config_and_warns_about_an_absent_camera(tmp_path, port):
    calib = tmp_path / "calib.yaml"
    calib.write_text("focal_px: 200.0\nbaseline_m: 0.063\nwidth: 320\nheight: 240\n")
    (tmp_path / "params.yaml").write_bytes(GOOD)
    cfg = config(port, tmp_path / "params.yaml", source={"kind": "uvc", "device": "/dev/video97", "width": 320,
                                                          "height": 240}, calibration=str(calib))
    daemon = run_daemon(tmp_path, cfg, "--check")
    code = daemon.wait(120)
    out = daemon.proc.stdout.read().decode()
    daemon.kill()
    assert code == 0, daemon.stderr()
    assert f"checked: parameters {tmp_path / 'params.yaml'}: hash {PARAMS_64.hash()}, measure a test render" in out
    assert "warning: camera /dev/video97 is not present now" in out and "config valid:" in out
