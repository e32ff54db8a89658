"""The in-flight rig check: logs the figure, warns once past the threshold, and runs on its own thread."""

import logging
import threading

import cv2
import numpy as np

from uav_depth.daemon.rigwatch import RigCheckConfig, RigWatch
from uav_depth.sim.scene import Scene, SceneConfig


def _pair(dy):
    cfg = SceneConfig(width=480, height=270, focal_px=260.0, branch_distance_m=1.5, seed=5)
    fr = Scene(cfg).render(rng=np.random.default_rng(5))
    m = np.float32([[1, 0, 0], [0, 1, dy]])
    right = cv2.warpAffine(fr.right, m, (480, 270), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return fr.left, right


def test_misalignment_is_logged_and_warned_once(caplog):
    sent = []
    watch = RigWatch(RigCheckConfig(interval_s=60.0), sent.append)
    assert watch.check_now() is None                 # no frame yet: nothing to check
    watch.offer(*_pair(0.0))
    with caplog.at_level(logging.INFO, logger="uav_depth.rigcheck"):
        assert watch.check_now().ok is True
        watch.offer(*_pair(1.5))
        assert watch.check_now().ok is False
        watch.check_now()
    assert any("rig check: OK" in r.message for r in caplog.records)
    assert any(r.levelno == logging.WARNING and "MISALIGNED" in r.message for r in caplog.records)
    assert len(sent) == 1 and "misaligned 1.5px" in sent[0]


def test_runs_periodically_on_its_thread_and_stops():
    sent = []
    watch = RigWatch(RigCheckConfig(interval_s=0.2, threshold_px=0.5), sent.append)
    watch.offer(*_pair(1.0))
    stop = threading.Event()
    watch.start(stop)
    deadline = threading.Event()
    for _ in range(200):
        if watch.last is not None:
            break
        deadline.wait(0.1)
    stop.set()
    assert watch.join(15)
    assert watch.last is not None and abs(watch.last.vertical_median_px - 1.0) <= 0.1
    assert sent and "misaligned" in sent[0]
