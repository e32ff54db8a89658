"""The background frame logger: log layout, every Nth frame, on demand, disk budget, write failures."""

import shutil
import time

import numpy as np
import pytest

from uav_depth.core.calibration import Calibration
from uav_depth.daemon.config import LoggingConfig
from uav_depth.daemon.framelog import FrameLogger, tree_size
from uav_depth.core.session import find_sessions, iter_frames

CALIB = Calibration(focal_px=200.0, baseline_m=0.063, width=64, height=48)


def pair(seed):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, (48, 64), np.uint8), rng.integers(0, 255, (48, 64), np.uint8)


def feed(logger, n, start=0):
    for i in range(start, start + n):
        left, right = pair(i)
        logger.consider(i, left, right, {"time_s": i * 0.1, "branch_distance_m": 1.0},
                        reference=np.full((48, 64), 12.6, np.float32), reference_source={"kind": "synthetic"})
        time.sleep(0.02)


def test_every_nth_frame_in_the_log_layout(tmp_path):
    logger = FrameLogger(LoggingConfig(dir=tmp_path, every_n=2), CALIB, "synthetic").start()
    feed(logger, 6)
    assert logger.close(5.0) == 0
    (session,) = find_sessions(tmp_path)
    assert session.path.name.endswith("-synthetic") and session.calibration() == CALIB
    frames = session.frames()
    assert [f.frame_id for f in frames] == ["000000", "000002", "000004"]
    left, _ = frames[1].load_pair()
    assert np.array_equal(left, pair(2)[0])
    assert frames[1].load_meta()["time_s"] == pytest.approx(0.2)
    assert np.allclose(frames[1].load_reference(), 12.6)
    assert len(list(iter_frames(tmp_path, require_reference=True))) == 3


def test_on_demand_only(tmp_path):
    logger = FrameLogger(LoggingConfig(dir=tmp_path, every_n=0), CALIB, "uvc").start()
    feed(logger, 3)
    logger.request()
    feed(logger, 3, start=3)
    logger.close(5.0)
    assert [f.frame_id for f in find_sessions(tmp_path)[0].frames()] == ["000003"]


def old_session(root, name, mb):
    s = root / name / "frames"
    s.mkdir(parents=True)
    (s / "000000_left.png").write_bytes(b"\0" * int(mb * 1024 * 1024))
    return root / name


def test_budget_removes_the_oldest_sessions_first(tmp_path):
    a = old_session(tmp_path, "20200101-000000-uvc", 0.6)
    b = old_session(tmp_path, "20200102-000000-uvc", 0.6)
    logger = FrameLogger(LoggingConfig(dir=tmp_path, every_n=1, max_mb=1.0), CALIB, "uvc").start()
    feed(logger, 2)
    logger.close(5.0)
    assert not a.exists() and b.exists()
    assert logger.written == 2 and logger.stopped is None
    assert tree_size(tmp_path) <= 1024 * 1024


def test_current_session_filling_the_budget_stops_logging(tmp_path):
    reasons = []
    logger = FrameLogger(LoggingConfig(dir=tmp_path, every_n=1, max_mb=0.03), CALIB, "uvc",
                         on_stop=reasons.append).start()
    feed(logger, 10)
    logger.close(5.0)
    assert reasons and "disk budget of 0.03 MB" in reasons[0] and len(reasons) == 1
    assert 0 < logger.written < 10
    assert not logger.consider(99, *pair(99), {})       # stopped: nothing more is queued


def test_a_write_error_stops_logging_and_says_why(tmp_path):
    reasons = []
    logger = FrameLogger(LoggingConfig(dir=tmp_path, every_n=1), CALIB, "uvc", on_stop=reasons.append).start()
    feed(logger, 1)
    deadline = time.monotonic() + 5
    while logger.written < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    frames_dir = logger.session.frames_dir
    shutil.rmtree(frames_dir)
    frames_dir.write_text("not a directory any more")     # writes now fail with a real OSError
    feed(logger, 2, start=1)
    logger.close(5.0)
    assert reasons and reasons[0].startswith(f"cannot write to {tmp_path}")
    assert logger.written == 1


def test_an_unusable_log_directory_stops_logging_at_start(tmp_path):
    (tmp_path / "file").write_text("x")
    reasons = []
    logger = FrameLogger(LoggingConfig(dir=tmp_path / "file" / "logs"), CALIB, "uvc",
                         on_stop=reasons.append).start()
    assert logger.stopped and "cannot create log directory" in reasons[0]
    assert not logger.consider(0, *pair(0), {})
    assert logger.close(1.0) == 0
