"""Frame sources: the table, synthetic truth and caching, replay pacing, hardware that is not there."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from uav_depth.daemon.config import run_config_from_dict
from uav_depth.core.errors import CalibrationError, SourceError
from uav_depth.core.rectify import Rectifier
from uav_depth.sim.scene import Pose, SceneConfig, write_session
from uav_depth.cli.sources import SOURCES
from uav_depth.daemon.sources import EndOfStream, create_source
from uav_depth.core.frames import device_capture_time
from uav_depth.sim.source import SyntheticSource
from uav_depth.daemon.sources.uvc import read_zed_conf, split_side_by_side

SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 1.0, "seed": 4}


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def source_config(**source):
    return run_config_from_dict({"source": source}, sources=SOURCES).source


def test_table_names_and_cli_listing():
    assert list(SOURCES) == ["synthetic", "replay", "uvc", "oak"]
    out = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "sources", "--keys"], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    for kind in SOURCES:
        assert out.count(f"\n{kind} ") + out.startswith(f"{kind} ") == 1
    assert "approach_speed_mps" in out and "zed_calibration" in out


def test_synthetic_frames_carry_truth_and_reference_and_are_cached_when_static():
    clock = FakeClock()
    src = create_source(source_config(kind="synthetic", fps=10, scene=SCENE), clock=clock)
    src.open()
    frames = []
    for _ in range(4):
        frames.append(src.read(1.0))
        clock.t += 0.1
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert all(f.truth_m == pytest.approx(1.0, rel=5e-3) for f in frames)
    assert src.renders == 1                                   # the pose never moved: rendered once
    assert all(np.array_equal(f.left, frames[0].left) for f in frames)
    assert frames[0].reference.shape == (240, 320) and frames[0].reference_source["kind"] == "synthetic"
    assert src.calibration.focal_px == 200.0


def test_synthetic_paces_at_fps():
    clock = FakeClock()
    src = create_source(source_config(kind="synthetic", fps=10, scene=SCENE), clock=clock)
    src.open()
    assert src.read(1.0).index == 0
    clock.t += 0.05
    start = time.monotonic()
    assert src.read(0.01) is None                              # frame 1 is due in 50 ms: not yet
    assert time.monotonic() - start < 0.5
    clock.t += 0.3                                             # late: the latest due frame, no backlog
    assert src.read(1.0).index == 3


def test_scripted_approach_moves_the_branch_and_stops():
    clock = FakeClock()
    src = create_source(source_config(kind="synthetic", fps=10, approach_speed_mps=0.2, stop_distance_m=0.7,
                                      scene=SCENE), clock=clock)
    src.open()
    truths = []
    for _ in range(5):
        truths.append(src.read(1.0).truth_m)
        clock.t += 1.0
    assert truths[:3] == pytest.approx([1.0, 0.8, 0.7], rel=0.01)
    assert truths[3:] == pytest.approx([0.7, 0.7], rel=0.01)
    assert src.renders == 3                                    # standing still at 0.7 m: no new render


def test_receding_and_the_pose_provider():
    cfg = source_config(kind="synthetic", fps=10, approach_speed_mps=-0.5, scene=SCENE)
    assert cfg.scripted_distance(2.0) == pytest.approx(2.0)
    assert cfg.scripted_distance(100.0) == pytest.approx(7.0)    # stops 1 m before the background
    clock = FakeClock()
    seen = []

    def provider(t):
        seen.append(t)
        return Pose.forward(0.25)

    src = SyntheticSource(cfg, pose_provider=provider, clock=clock)
    src.open()
    clock.t += 0.5
    frame = src.read(1.0)
    assert seen[-1] == pytest.approx(0.5) and frame.truth_m == pytest.approx(0.75, rel=0.01)


def test_a_failing_pose_provider_is_a_lost_camera():
    def broken(t):
        raise RuntimeError("no autopilot")

    src = SyntheticSource(source_config(kind="synthetic", scene=SCENE), pose_provider=broken)
    with pytest.raises(SourceError, match="pose provider failed: RuntimeError: no autopilot"):
        src.open()


def test_replay_paces_loops_and_ends(tmp_path):
    write_session(tmp_path / "s", 3, seed=2, base=SceneConfig(**{**SCENE, "branch_distance_m": 1.2}),
                  vary_scenes=False)
    clock = FakeClock()
    src = create_source(source_config(kind="replay", path=str(tmp_path / "s"), rate_hz=5), clock=clock)
    src.open()
    assert src.calibration.focal_px == 200.0
    first = src.read(1.0)
    assert first.truth_m == pytest.approx(1.2, rel=5e-3) and first.left.shape == (240, 320)
    assert src.read(0.01) is None                               # next one due 0.2 s later
    clock.t += 0.2
    assert src.read(1.0).index == 1
    clock.t += 0.2
    assert src.read(1.0).index == 2
    with pytest.raises(EndOfStream, match="all 3 frames delivered"):
        src.read(1.0)
    looping = create_source(source_config(kind="replay", path=str(tmp_path / "s"), rate_hz=5, loop=True),
                            clock=clock)
    looping.open()
    indices = []
    for _ in range(5):
        indices.append(looping.read(1.0).index)
        clock.t += 0.2
    assert indices == [0, 1, 2, 3, 4]


def test_replay_of_nothing_says_what_is_missing(tmp_path):
    with pytest.raises(SourceError, match="log directory not found"):
        create_source(source_config(kind="replay", path=str(tmp_path / "nope"))).open()


def test_missing_uvc_camera_fails_fast_and_names_the_device():
    src = create_source(source_config(kind="uvc", device="/dev/video97"))
    start = time.monotonic()
    with pytest.raises(SourceError, match=r"uvc: camera /dev/video97 not found \(video devices present: "):
        src.open()
    assert time.monotonic() - start < 1.0


def test_missing_oak_fails_fast_with_a_clear_message():
    src = create_source(source_config(kind="oak"))
    start = time.monotonic()
    with pytest.raises(SourceError, match="oak: no OAK device found"):
        src.open()
    took = time.monotonic() - start
    assert took < 3.0, f"device check took {took:.2f} s"    # depthai's pipeline build would block far longer


def test_side_by_side_split():
    frame = np.arange(4 * 10 * 3, dtype=np.uint8).reshape(4, 10, 3)
    left, right = split_side_by_side(frame)
    assert left.shape == right.shape == (4, 5, 3)
    assert np.array_equal(left, frame[:, :5]) and np.array_equal(right, frame[:, 5:])
    with pytest.raises(SourceError, match="width 9 is odd"):
        split_side_by_side(frame[:, :9])


ZED_CONF = """[LEFT_CAM_HD]
fx=700.5
fy=700.1
cx=640.2
cy=360.7
k1=-0.17
k2=0.027
p1=0.0
p2=0.0
k3=0.0

[RIGHT_CAM_HD]
fx=699.8
fy=699.9
cx=639.1
cy=359.2
k1=-0.171
k2=0.026
p1=0.0
p2=0.0
k3=0.0

[STEREO]
Baseline=63.02
TY_HD=0.12
TZ_HD=-0.31
CV_HD=0.0021
RX_HD=0.0013
RZ_HD=-0.0004
"""


def test_zed_calibration_file(tmp_path):
    path = tmp_path / "SN12345678.conf"
    path.write_text(ZED_CONF)
    calib = read_zed_conf(path, 1280, 720)
    assert calib.is_raw and calib.baseline_m == pytest.approx(0.06302)
    assert calib.t == pytest.approx((-0.06302, 0.00012, -0.00031))
    assert np.asarray(calib.k_left)[0, 0] == 700.5 and np.asarray(calib.d_right)[0] == -0.171
    r = np.asarray(calib.r)
    assert np.allclose(r @ r.T, np.eye(3)) and r[0, 2] == pytest.approx(0.0021, abs=1e-6)
    rect = Rectifier(calib)
    assert rect.calibration.baseline_m == pytest.approx(np.linalg.norm(calib.t), rel=1e-6)
    assert 650 < rect.calibration.focal_px < 760
    with pytest.raises(CalibrationError, match="eye widths"):
        read_zed_conf(path, 1000, 720)
    with pytest.raises(CalibrationError, match=r"no \[LEFT_CAM_VGA\] section"):
        read_zed_conf(path, 672, 376)


def test_a_zed_calibration_file_is_read_within_a_bound(tmp_path):
    big = tmp_path / "SN1.conf"
    big.write_text(ZED_CONF + "; padding\n" * 7000)
    with pytest.raises(CalibrationError, match=r"SN1\.conf: ZED calibration file is \d+ bytes, more than the 64 KiB"):
        read_zed_conf(big, 1280, 720)
    fifo = tmp_path / "SN2.conf"
    os.mkfifo(fifo)
    with pytest.raises(CalibrationError, match=r"SN2\.conf: ZED calibration file is not a regular file"):
        read_zed_conf(fifo, 1280, 720)


def test_device_capture_time_takes_the_earliest_plausible_device_stamp():
    assert device_capture_time([99.95, 99.97], now=100.0) == 99.95        # the older eye: ages never understated
    assert device_capture_time([None, 99.9], now=100.0) == 99.9
    assert device_capture_time([None], now=100.0) == 100.0                 # no device stamp: the receive time
    assert device_capture_time([100.5], now=100.0) == 100.0                # in the future: another clock
    assert device_capture_time([1.7e9], now=100.0) == 100.0                # wall clock, not monotonic
    assert device_capture_time([90.0], now=100.0) == 100.0                 # far behind: relative to something else


class FakeCapture:
    """The hardware boundary of UvcSource: cv2.VideoCapture, with a V4L2 buffer timestamp (ms)."""

    def __init__(self, stamp_ms, image):
        self.stamp_ms, self.image = stamp_ms, image

    def set(self, prop, value):
        return True

    def get(self, prop):
        import cv2

        return self.stamp_ms if prop == cv2.CAP_PROP_POS_MSEC else 0.0

    def grab(self):
        return True

    def retrieve(self):
        return True, self.image


def test_uvc_frames_carry_the_v4l2_buffer_timestamp():
    src = create_source(source_config(kind="uvc", device="/dev/video97", right_device="/dev/video96",
                                      width=16, height=16, grey=False))
    img = np.zeros((16, 16, 3), np.uint8)
    t = time.monotonic()
    src._caps = [FakeCapture((t - 0.040) * 1000.0, img), FakeCapture((t - 0.035) * 1000.0, img)]
    frame = src.read(0.1)
    assert frame.t_capture == pytest.approx(t - 0.040, abs=1e-6)           # 40 ms before the host got it
    src._caps = [FakeCapture(0.0, img), FakeCapture(0.0, img)]              # a driver without timestamps
    before = time.monotonic()
    assert before <= src.read(0.1).t_capture <= time.monotonic()


def test_a_two_camera_pair_captured_more_than_half_a_frame_apart_is_dropped_and_counted():
    src = create_source(source_config(kind="uvc", device="/dev/video97", right_device="/dev/video96",
                                      width=16, height=16, fps=30.0))
    img = np.zeros((16, 16), np.uint8)
    t = time.monotonic()
    src._caps = [FakeCapture((t - 0.040) * 1000.0, img), FakeCapture((t - 0.020) * 1000.0, img)]   # 20 ms > 16.7
    assert src.read(0.1) is None and src.out_of_sync == 1
    assert src.notes == ("1 stereo pair dropped (eyes captured more than half a frame apart)",)
    src._caps = [FakeCapture((t - 0.040) * 1000.0, img), FakeCapture((t - 0.025) * 1000.0, img)]   # 15 ms: kept
    assert src.read(0.1).t_capture == pytest.approx(t - 0.040, abs=1e-6)
    assert src.out_of_sync == 1


class FakeImgFrame:
    def __init__(self, t, seq=7):
        self.t, self.seq = t, seq

    def getTimestamp(self):
        import datetime

        return datetime.timedelta(seconds=self.t)

    def getSequenceNum(self):
        return self.seq

    def getFrame(self):
        return np.zeros((4, 8), np.uint8)


class FakeQueue:
    def __init__(self, msg):
        self.msg = msg

    def get(self, timeout):
        return self.msg


def test_oak_frames_carry_the_device_timestamp():
    src = create_source(source_config(kind="oak"))
    t = time.monotonic()
    src._pipeline = type("Running", (), {"isRunning": lambda self: True})()
    src._queues = {"left": FakeQueue(FakeImgFrame(t - 0.030)), "right": FakeQueue(FakeImgFrame(t - 0.030))}
    assert src.read(0.1).t_capture == pytest.approx(t - 0.030, abs=1e-6)
