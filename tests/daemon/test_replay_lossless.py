"""Replay: what the one-slot mailbox dropped is counted and said; source.lossless processes every frame,
and the replay's last frames are processed before the daemon stops (on a loaded machine too)."""

import logging
import threading

import numpy as np

from uav_depth.cli.sources import SOURCES
from uav_depth.core.calibration import Calibration
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.core.session import SessionWriter
from uav_depth.daemon.capture import Mailbox
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.daemon.service import Service
from uav_depth.sim.scene import Scene, SceneConfig

N = 6


def session(path):
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=0.8, branch_radius_m=0.04, seed=1)
    fr = Scene(cfg).render(rng=np.random.default_rng(1))
    w = SessionWriter(path, Calibration(focal_px=200.0, baseline_m=0.063, width=320, height=240))
    for i in range(N):
        w.write(i, fr.left, fr.right, meta={"branch_distance_m": 0.8})
    return path


def service(rx, tmp_path, **source):
    params = tmp_path / "params.yaml"
    save_params(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64}), params)
    return Service(run_config_from_dict({
        "source": {"kind": "replay", "path": str(session(tmp_path / "s")), "rate_hz": 1000, **source},
        "params_file": str(params), "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}"}}, sources=SOURCES))


def test_lossless_replay_processes_every_frame(rx, tmp_path, caplog):
    svc = service(rx, tmp_path, lossless=True)
    with caplog.at_level(logging.INFO, logger="uav_depth.service"):
        report = svc.run(threading.Event())
    assert report.clean and svc.ended
    assert svc.stats.frames == N and svc.mailbox.dropped == 0
    assert any(f"delivered {N} frames: {N} processed, 0 dropped" in r.message for r in caplog.records)


def test_paced_replay_says_what_it_dropped(rx, tmp_path, caplog):
    # at 1000 fps the pipeline (tens of ms a frame) cannot keep up: frames are dropped, and said so
    svc = service(rx, tmp_path)
    with caplog.at_level(logging.INFO, logger="uav_depth.service"):
        svc.run(threading.Event())
    dropped = svc.mailbox.dropped
    assert dropped >= 1 and svc.frames_done + dropped == N
    line = next(r.message for r in caplog.records if f"delivered {N} frames" in r.message)
    assert f"{dropped} dropped" in line and "source.lossless: true" in line


def test_a_lossless_put_waits_for_the_slot():
    box, stop = Mailbox(), threading.Event()
    box.put("a", stop)
    t = threading.Thread(target=box.put, args=("b", stop))
    t.start()
    t.join(0.3)
    assert t.is_alive()                 # waiting: "a" is not taken yet
    assert box.get(1.0) == "a"
    t.join(2)
    assert not t.is_alive() and box.get(1.0) == "b" and box.dropped == 0
