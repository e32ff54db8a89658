"""Faults while running against the real daemon process: replay metadata, the signing key's path, free space.

Each fault ends in one line and the documented exit code (78 for anything in a
config, parameter or key file), or, while flying, in one log line with the last
good parameters kept: never a traceback, a restart loop or a silent change.
See docs/operations.md.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np

from uav_depth.core.session import SessionWriter
from uav_depth.sim.scene import Scene, SceneConfig

from mavlink_peer import Receiver
from daemon_process import GOOD, KEY_HEX, SCENE, config, run_daemon


# -- replay, signing key path, free space -------------------------------------------------------------

def test_a_replay_frame_whose_meta_is_not_utf8_is_one_line_and_the_replay_ends(tmp_path, port):
    cfg = SceneConfig(**SCENE)
    writer = SessionWriter(tmp_path / "log", cfg.calibration)
    scene = Scene(cfg)
    for i in range(3):
        frame = scene.render(rng=np.random.default_rng(i))
        writer.write(i, frame.left, frame.right, meta={"time_s": 0.2 * i, "branch_distance_m": 0.8})
    bad = writer.session.frames()[1]
    bad.meta_path.write_bytes(b'{"time_s": 0.2, "note": "caf\xe9"}')
    (tmp_path / "params.yaml").write_bytes(GOOD)
    daemon = run_daemon(tmp_path, config(port, tmp_path / "params.yaml",
                                         source={"kind": "replay", "path": str(tmp_path / "log"), "rate_hz": 2}))
    try:
        code = daemon.wait(180)      # ends by itself: not a lost camera, not a restart loop
    finally:
        daemon.kill()
    err = daemon.stderr()
    assert code == 0 and "Traceback" not in err, err[-3000:]
    skipped = [ln for ln in err.splitlines() if "skipping" in ln]
    assert len(skipped) == 1 and "frame metadata is not UTF-8 text" in skipped[0], err[-3000:]
    assert "camera lost" not in err and "frames delivered" in err


def test_a_relative_signing_key_file_is_found_beside_the_config(tmp_path):
    rx = Receiver()
    rx.conn.setup_signing(bytes.fromhex(KEY_HEX.decode().strip()), sign_outgoing=False)
    conf = tmp_path / "etc"
    elsewhere = tmp_path / "elsewhere"
    conf.mkdir()
    elsewhere.mkdir()
    (conf / "params.yaml").write_bytes(GOOD)
    (conf / "mavlink.key").write_bytes(KEY_HEX)
    os.chmod(conf / "mavlink.key", 0o600)
    cfg = config(rx.port, "params.yaml", mavlink={"signing_key_file": "mavlink.key"})
    daemon = run_daemon(conf, cfg, cwd=elsewhere)
    try:
        assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR")) >= 3, timeout=180), daemon.stderr()[-3000:]
        daemon.proc.send_signal(signal.SIGTERM)
        code = daemon.wait(60)
    finally:
        daemon.kill()
        rx.close()
    assert code == 0, daemon.stderr()[-3000:]
    signed = [m for m in rx.of("DISTANCE_SENSOR") if m.get_signed()]
    assert signed, "messages are not signed"


def test_frame_logging_stops_at_the_free_space_floor_and_the_daemon_flies_on(tmp_path):
    rx = Receiver()
    logs = tmp_path / "logs"
    (tmp_path / "params.yaml").write_bytes(GOOD)
    # A floor above any disk's free space: the first frame would take the disk below it.
    cfg = config(rx.port, tmp_path / "params.yaml", logging={"dir": str(logs), "every_n": 1, "min_free_mb": 1e9})
    daemon = run_daemon(tmp_path, cfg)
    try:
        daemon.wait_for(lambda: "frame logging stopped: free space" in daemon.stderr(), 180, "logging to stop")
        t = time.monotonic()
        assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR", since=t)) >= 10, timeout=10)
        daemon.proc.send_signal(signal.SIGTERM)
        code = daemon.wait(60)
    finally:
        daemon.kill()
        rx.close()
    err = daemon.stderr()
    assert code == 0 and "Traceback" not in err
    assert "below logging.min_free_mb 1e+09 MB" in err
    assert not list(logs.rglob("*_left.png"))
    assert any("logging stopped" in t for t in rx.texts())
