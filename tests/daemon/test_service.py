"""The service in-process, against a real pymavlink endpoint: staleness, camera loss, hot reload, start-up failures.

The tests hold on a loaded machine (issue 15): waits have a long deadline, the staleness limit and the
camera timeout are generous except where they are what is tested, and timing claims are checked on the
estimates' own capture stamps (time_boot_ms counts CLOCK_MONOTONIC, as time.monotonic does).
"""

import threading
import time

import pytest

from uav_depth.cli.sources import SOURCES
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.core.errors import ConfigError, SourceError
from uav_depth.core.fileio import atomic_write_text
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.sim.scene import Pose
from uav_depth.daemon.service import Service
from uav_depth.daemon.stage import check_roi_against_compute


SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 0.8, "branch_radius_m": 0.04,
         "seed": 1}
PARAMS_64 = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})


#: Deadline for what a loaded machine takes its time over (never reached when things work).
PATIENCE_S = 120


def config(rx, **sections):
    # max_age_ms 499 (the largest allowed) and frame_timeout_s 10: a loaded machine neither starves the
    # readings nor loses the camera; the tests of those rules set their own.
    data = {"source": {"kind": "synthetic", "fps": 10, "scene": SCENE},
            "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 20},
            "ranging": {"max_age_ms": 499},
            "service": {"status_interval_s": 0.5, "reconnect_min_s": 0.05, "reconnect_max_s": 0.1,
                        "frame_timeout_s": 10.0, "params_poll_s": 0.1}}
    for k, v in sections.items():
        data[k] = {**data.get(k, {}), **v} if isinstance(v, dict) and k != "source" else v
    return run_config_from_dict(data, sources=SOURCES)


class Running:
    """Run a Service on a thread for the duration of a with-block."""

    def __init__(self, service):
        self.service = service
        self.stop = threading.Event()
        self.report = None
        self.error = None

    def __enter__(self):
        def target():
            try:
                self.report = self.service.run(self.stop)
            except Exception as exc:   # surfaced by the test below
                self.error = exc
        self.thread = threading.Thread(target=target, daemon=True)
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(10)
        assert not self.thread.is_alive()


@pytest.fixture
def params_file(tmp_path):
    path = tmp_path / "params.yaml"
    save_params(PARAMS_64, path)
    return path


def test_a_stale_estimate_is_never_sent(rx, params_file):
    # Every estimate is older than 1 ms by the time it is published: the frames are measured
    # (valid distances) but none may go out, not even as "no measurement" (that reads as clear).
    svc = Service(config(rx, params_file=str(params_file), ranging={"max_age_ms": 1}))
    with Running(svc):
        assert rx.wait(lambda: len(rx.of("HEARTBEAT")) >= 3, PATIENCE_S)
        assert rx.wait(lambda: "uav-depth: blind (stale)" in rx.texts(), PATIENCE_S)
    assert svc.last_estimate is not None and svc.last_estimate.measurement.valid
    assert svc.stats.frames >= 3
    assert rx.of("DISTANCE_SENSOR") == []


def test_fresh_estimates_are_sent_and_the_distance_is_right(rx, params_file):
    svc = Service(config(rx, params_file=str(params_file)))
    with Running(svc) as run:
        assert rx.wait(lambda: len([m for m in rx.of("DISTANCE_SENSOR") if m.signal_quality > 1]) >= 10, PATIENCE_S)
    assert run.report.clean
    valid = [m for m in rx.of("DISTANCE_SENSOR") if m.signal_quality > 1]
    assert all(abs(m.current_distance - 80) <= 3 for m in valid)     # 0.8 m within 3 %


def test_camera_loss_sends_no_measurement_and_recovers(rx, params_file):
    lost = threading.Event()

    def pose(t):
        if lost.is_set():
            raise SourceError("synthetic: camera unplugged (test)")
        return Pose.forward(0.0)

    svc = Service(config(rx, params_file=str(params_file), ranging={"max_age_ms": 300}), pose_provider=pose)
    with Running(svc):
        assert rx.wait(lambda: any(m.signal_quality > 1 for m in rx.of("DISTANCE_SENSOR")), PATIENCE_S)
        lost.set()
        t_lost = time.monotonic()
        assert rx.wait(lambda: "uav-depth: camera lost" in rx.texts(), PATIENCE_S)
        time.sleep(1.6)                 # long enough for at least one HEARTBEAT (1 Hz)
        lost.clear()
        assert rx.wait(lambda: "uav-depth: camera back" in rx.texts(), PATIENCE_S)
        t_back = time.monotonic()
        assert rx.wait(lambda: any(m.signal_quality > 1 for m in rx.of("DISTANCE_SENSOR", since=t_back)),
                       PATIENCE_S)
    # blind: nothing measured after the loss goes out (by the readings' own capture stamps), the autopilot
    # times out; what arrived after the loss was captured before it
    gap = [m for t, m in rx.msgs if m.get_type() == "DISTANCE_SENSOR" and t_lost < t < t_back]
    assert all(m.time_boot_ms <= t_lost * 1000.0 for m in gap), [m.time_boot_ms - t_lost * 1000.0 for m in gap]
    assert "uav-depth: blind (camera lost)" in rx.texts()
    beats = [m.system_status for t, m in rx.msgs if m.get_type() == "HEARTBEAT" and t_lost + 0.2 < t < t_back]
    assert 5 in beats                                              # MAV_STATE_CRITICAL while the camera is gone


def test_hot_reload_swaps_valid_and_rejects_invalid_parameters(rx, params_file):
    svc = Service(config(rx, params_file=str(params_file)))
    with Running(svc):
        assert rx.wait(lambda: svc.stats.frames >= 2, PATIENCE_S)
        first = svc.stage
        new = PARAMS_64.replace(**{"sgbm.uniqueness_ratio": 15})
        save_params(new, params_file)
        assert rx.wait(lambda: svc.stage.params == new, PATIENCE_S), "new parameters not picked up"
        assert rx.wait(lambda: f"uav-depth: params {new.hash()[:8]} loaded" in rx.texts(), PATIENCE_S)
        assert rx.wait(lambda: svc.last_estimate.params_hash == new.hash(), PATIENCE_S)   # frames use the new stage
        swapped = svc.stage
        atomic_write_text(params_file, "sgbm:\n  num_disparities: 40\n")
        assert rx.wait(lambda: f"uav-depth: params rejected, kept {new.hash()[:8]}" in rx.texts(), PATIENCE_S)
        t_bad = time.monotonic()
        assert rx.wait(lambda: sum(m.signal_quality > 1 for m in rx.of("DISTANCE_SENSOR", since=t_bad)) >= 10,
                       PATIENCE_S)
        assert svc.stage is swapped and svc.stage is not first


def test_missing_camera_fails_start_up_and_leaves_nothing_running(rx):
    before = {t.name for t in threading.enumerate()}
    svc = Service(config(rx, source={"kind": "uvc", "device": "/dev/video98"}))
    with pytest.raises(SourceError, match="/dev/video98 not found"):
        svc.run(threading.Event())
    time.sleep(0.3)
    left = {t.name for t in threading.enumerate()} - before
    assert not left & {"capture", "stereo", "mavlink-clock", "mavlink-io", "params-watch"}


def test_calibration_that_does_not_fit_the_frames_fails_start_up(rx):
    svc = Service(config(rx, calibration={"focal_px": 200.0, "baseline_m": 0.063, "width": 640, "height": 480}))
    with pytest.raises(ConfigError, match="frames are 320x240 but the calibration is for 640x480"):
        svc.run(threading.Event())


def test_an_invalid_parameter_file_fails_start_up(rx, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sgbm:\n  block_size: 4\n")
    with pytest.raises(ConfigError, match="sgbm.block_size must be odd, but got 4"):
        Service(config(rx, params_file=str(bad))).run(threading.Event())


def test_ranging_roi_outside_the_matching_roi_is_warned():
    params = PARAMS_64.replace(**{"compute.roi": (0.25, 0.25, 0.75, 0.75)})
    assert check_roi_against_compute((213, 120, 426, 240), params, 640, 360) is None
    warning = check_roi_against_compute((0, 0, 640, 360), params, 640, 360)
    assert "reaches outside the parameters' matching region compute.roi (= [160, 90, 480, 270] px" in warning
    assert check_roi_against_compute((0, 0, 640, 360), PARAMS_64, 640, 360) is None   # the whole image


class HangingSource:
    """A camera driver that delivers one frame, then hangs in read() (seen with V4L2 on a bad USB hub)."""

    kind = "hanging"

    def __init__(self):
        import numpy as np

        from uav_depth.sim.scene import Scene, SceneConfig
        from uav_depth.daemon.sources import Frame

        cfg = SceneConfig(**SCENE)
        self.calibration = cfg.calibration
        self._pair = Scene(cfg).render(rng=np.random.default_rng(0))
        self._frame = lambda: Frame(self._pair.left, self._pair.right, 0)
        self.release = threading.Event()
        self.reads = 0

    def describe(self):
        return "a source that hangs"

    def open(self):
        pass

    def read(self, timeout_s):
        self.reads += 1
        if self.reads == 1:
            return self._frame()
        self.release.wait(60)     # ignores timeout_s, like the driver
        return None

    def close(self):
        pass


def test_a_hung_source_stops_the_watchdog_and_shutdown_stays_bounded(rx):
    source = HangingSource()
    cfg = config(rx, service={"stall_timeout_s": 0.5, "shutdown_timeout_s": 0.3})
    svc = Service(cfg, source=source)
    stop = threading.Event()
    result = {}
    runner = threading.Thread(target=lambda: result.setdefault("report", svc.run(stop)), daemon=True)
    try:
        runner.start()
        assert rx.wait(lambda: svc.stats.frames >= 1 and source.reads >= 2, PATIENCE_S)
        assert svc.healthy()
        assert rx.wait(lambda: not svc.healthy(), timeout=PATIENCE_S)   # no more WATCHDOG=1: systemd restarts us
        stop.set()
        runner.join(30)
        report = result["report"]
        # bounded by shutdown_timeout_s (0.3 s, plus what a loaded machine adds), not by the hung read (60 s)
        assert report.duration_s < 0.3 + 10.0
        assert any(item.startswith("the capture thread (stuck for") for item in report.abandoned), report.abandoned
    finally:
        source.release.set()


def test_a_replay_of_a_logged_session_runs_to_its_end(rx, tmp_path, params_file):
    """Frames the daemon logged replay through the daemon again, paced at their recorded time_s."""
    logs = tmp_path / "logs"
    svc = Service(config(rx, params_file=str(params_file), logging={"dir": str(logs), "every_n": 2}))
    with Running(svc):
        assert rx.wait(lambda: svc.framelog is not None and svc.framelog.written >= 4, PATIENCE_S)
    replay = Service(config(rx, params_file=str(params_file), source={"kind": "replay", "path": str(logs)}))
    start = time.monotonic()
    report = replay.run(threading.Event())      # returns by itself after the last frame
    assert report.clean and replay.ended and "frames delivered" in replay.ended
    assert replay.stats.frames >= 4
    assert time.monotonic() - start > 0.5        # paced at the recorded 0.2 s per logged frame, not as fast as possible
    assert replay.last_estimate.truth_m == pytest.approx(0.8, rel=5e-3)
    assert replay.last_estimate.measurement.distance_m == pytest.approx(0.8, rel=0.03)


def test_a_pose_provider_needs_the_synthetic_source(rx):
    with pytest.raises(ConfigError, match="source.kind must be synthetic when a pose provider drives the rig"):
        Service(config(rx, source={"kind": "uvc"}), pose_provider=lambda t: Pose())


def test_the_outlier_gate_is_touched_by_the_stereo_thread_only(rx, params_file, monkeypatch):
    # A camera loss resets the gate; the capture thread sees the loss, the stereo thread uses the gate.
    from uav_depth.core.ranging import OutlierGate

    callers = set()
    for name in ("reset", "accept", "near", "too_close"):
        real = getattr(OutlierGate, name)

        def spy(self, *a, _real=real, **kw):
            callers.add(threading.current_thread().name)
            return _real(self, *a, **kw)
        monkeypatch.setattr(OutlierGate, name, spy)
    lost = threading.Event()

    def pose(t):
        if lost.is_set():
            raise SourceError("synthetic: camera unplugged (test)")
        return Pose.forward(0.0)

    svc = Service(config(rx, params_file=str(params_file)), pose_provider=pose)
    with Running(svc):
        assert rx.wait(lambda: svc.stats.frames >= 2, PATIENCE_S)
        lost.set()
        assert rx.wait(lambda: "uav-depth: camera lost" in rx.texts(), PATIENCE_S)
        lost.clear()
        assert rx.wait(lambda: "uav-depth: camera back" in rx.texts(), PATIENCE_S)
        frames = svc.stats.frames
        assert rx.wait(lambda: svc.stats.frames >= frames + 2, PATIENCE_S)
    assert callers == {"stereo"}


def test_nothing_is_sent_after_shutdown_began(rx, params_file):
    # The send clock is inside a send when the stop comes (held there by this link until "stopping" is
    # queued, or 0.3 s at most): that reading, and every other, must be on the wire before "stopping".
    from uav_depth.daemon.link.endpoint import MavlinkLink

    in_send, release = threading.Event(), threading.Event()

    class HeldLink(MavlinkLink):
        def distance_sensor(self, *args, **kwargs):
            if not in_send.is_set() and rx.of("DISTANCE_SENSOR"):
                in_send.set()
                release.wait(10)
            return super().distance_sensor(*args, **kwargs)

        def statustext(self, text, severity="info"):
            sent = super().statustext(text, severity)
            if text == "uav-depth: stopping":
                release.set()
            return sent

    cfg = config(rx, params_file=str(params_file))
    svc = Service(cfg, link=HeldLink(cfg.mavlink, 0.05, 0.1))
    stop = threading.Event()
    runner = threading.Thread(target=svc.run, args=(stop,), daemon=True)
    runner.start()
    assert in_send.wait(PATIENCE_S), "no reading was sent"
    stop.set()
    threading.Timer(0.3, release.set).start()
    runner.join(30)
    assert rx.wait(lambda: "uav-depth: stopping" in rx.texts(), 10)
    time.sleep(0.3)                               # anything still in flight on loopback
    t_stopping = next(t for t, m in rx.msgs if m.get_type() == "STATUSTEXT" and m.text == "uav-depth: stopping")
    after = [m.get_type() for t, m in rx.msgs if t > t_stopping and m.get_type() != "HEARTBEAT"]
    assert after == [], after
    assert [m.system_status for t, m in rx.msgs if m.get_type() == "HEARTBEAT" and t >= t_stopping] == [7]  # POWEROFF


def test_what_the_source_counts_is_in_the_status_line(rx, params_file):
    # A two-camera UVC rig counts the pairs it dropped as out of sync (daemon/sources/uvc.py); the
    # status line carries whatever the source says there.
    from uav_depth.daemon.sources import create_source

    cfg = config(rx, params_file=str(params_file))
    source = create_source(cfg.source)
    source.notes = ("3 stereo pairs dropped (eyes captured more than half a frame apart)",)
    svc = Service(cfg, source=source)
    with Running(svc):
        assert rx.wait(lambda: svc.stats.frames >= 1, PATIENCE_S)
        assert svc.status_line().endswith(", 3 stereo pairs dropped (eyes captured more than half a frame apart)")
