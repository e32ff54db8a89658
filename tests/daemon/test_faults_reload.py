"""Faults while flying against the real daemon process: a bad new parameter file keeps the last good one.

Each fault ends in one line and the documented exit code (78 for anything in a
config, parameter or key file), or, while flying, in one log line with the last
good parameters kept: never a traceback, a restart loop or a silent change.
See docs/operations.md.
"""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

import pytest

from uav_depth.core.params import DEFAULT_PARAMS

from mavlink_peer import Receiver
from daemon_process import GOOD, OVERSIZE_PARAMS, PARAMS_64, THREE_WAY_100, _params_with, alias_bomb, config, run_daemon


# -- while flying: a bad new file keeps the last good parameters --------------------------------------

@pytest.fixture(scope="module")
def flying(tmp_path_factory):
    """One daemon flying PARAMS_64 for the reload tests, with its peer."""
    d = tmp_path_factory.mktemp("flying")
    rx = Receiver()
    (d / "params.yaml").write_bytes(GOOD)
    daemon = run_daemon(d, config(rx.port, d / "params.yaml"))
    try:
        daemon.wait_for(lambda: "ready:" in daemon.stderr(), 180, "READY")
        yield d, rx, daemon
    finally:
        if daemon.proc.poll() is None:
            daemon.proc.send_signal(signal.SIGTERM)
            daemon.proc.wait(30)
        daemon.kill()
        rx.close()


def _replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".new")
    tmp.write_bytes(data)
    os.replace(tmp, path)


RELOAD_FAULTS = [
    pytest.param(b"sgbm:\n  p1: 600  # caf\xe9\n", r"parameter file is not UTF-8 text", id="not-utf8"),
    pytest.param(b"", r"must set at least one section", id="empty"),
    pytest.param(b"sgbm:\n  p1: 600\n  p1: 900\n", r"sgbm\.p1 is given twice", id="duplicate-key"),
    pytest.param(_params_with(**{"sgbm.p2": 40000}), r"sgbm\.p2 must be at most 32767", id="p2-over-16-bit-costs"),
    pytest.param(_params_with(**{"sgbm.num_disparities": 224, "sgbm.block_size": 31}),
                 r"must measure a test render", id="search-range-hides-the-roi"),
    pytest.param(b"\x00\x01\x02\x03", r"parameter file is a binary file", id="binary"),
    pytest.param(alias_bomb(), r"parameter file uses a YAML anchor \('l0'\) at line 1", id="alias-bomb"),
    pytest.param(THREE_WAY_100, r"sgbm\.uniqueness_ratio must be at most 99 with sgbm\.mode sgbm_3way",
                 id="3way-uniqueness-100"),
    pytest.param(OVERSIZE_PARAMS, r"parameter file is \d+ bytes, more than the 64 KiB", id="over-the-size-cap"),
]


@pytest.mark.parametrize("data,message", RELOAD_FAULTS)
def test_a_bad_new_parameter_file_keeps_the_last_good_and_the_daemon_flies(flying, data, message):
    d, rx, daemon = flying
    kept = f"uav-depth: params rejected, kept {PARAMS_64.hash()[:8]}"
    before = len(daemon.stderr().splitlines())
    t_replace = time.monotonic()
    _replace(d / "params.yaml", data)
    daemon.proc.send_signal(signal.SIGHUP)      # systemctl kill -s HUP, as the docs recommend
    daemon.wait_for(lambda: any(re.search(message, ln) for ln in daemon.stderr().splitlines()[before:]
                                if "parameters rejected, keeping " + PARAMS_64.hash() in ln), 60, "the rejection")
    assert rx.wait(lambda: kept in rx.texts(), timeout=10)
    daemon.proc.send_signal(signal.SIGHUP)      # the same file again: judged once, said once
    t = time.monotonic()
    assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR", since=t)) >= 10, timeout=10), "the messages stopped"
    err = daemon.stderr()
    assert daemon.proc.poll() is None and "Traceback" not in err
    assert "parameters reloaded" not in err
    rejections = [ln for ln in err.splitlines()[before:] if "parameters rejected" in ln]
    assert len(rejections) == 1, rejections
    assert sum(m.text == kept for m in rx.of("STATUSTEXT", since=t_replace)) == 1


def test_a_half_written_file_is_never_loaded(flying):
    d, rx, daemon = flying
    half = b"sgbm:\n  num_disparities: 32\n"
    full = half + b"  block_size: 7\nwls:\n  lambda: 9000.0\n"
    half_hash = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32}).hash()
    full_hash = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32, "sgbm.block_size": 7,
                                          "wls.lambda": 9000.0}).hash()
    with open(d / "params.yaml", "wb") as fh:     # written in place, in two parts, 3 s apart
        fh.write(half)
        fh.flush()
        os.fsync(fh.fileno())
        daemon.proc.send_signal(signal.SIGHUP)
        time.sleep(3.0)
        assert not any(half_hash[:8] in t for t in rx.texts()), "the half file was loaded"
        fh.write(full[len(half):])
    assert rx.wait(lambda: f"uav-depth: params {full_hash[:8]} loaded" in rx.texts(), timeout=60), \
        daemon.stderr()[-3000:]
    assert not any(half_hash[:8] in t for t in rx.texts())
    assert half_hash not in daemon.stderr() and "Traceback" not in daemon.stderr()
