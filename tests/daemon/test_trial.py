"""New parameters are first run in a child process: an OpenCV crash or hang there refuses them, nothing more.

The crash is real: OpenCV's 3-way SGBM divides by 100 - uniquenessRatio and dies of SIGFPE at 100.
The schema refuses that combination, so the parameters are built here without it
(``StereoParams(...)`` directly), as a combination the schema does not know about yet would arrive.
"""

import os
import signal
import threading
import time

import pytest

from uav_depth.cli.sources import SOURCES
from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS, SGBMParams, StereoParams, save_params
from uav_depth.daemon import stage as stage_module
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.core.ranging import RangingConfig, resolve_roi
from uav_depth.daemon.service import Service
from uav_depth.daemon.trial import Job, Trials

CALIB = Calibration(focal_px=200.0, baseline_m=0.063, width=320, height=240)
ROI = resolve_roi(None, 320, 240)
GOOD = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
#: What kills OpenCV 5.0.0 natively (SIGFPE in the 3-way matcher), past the schema.
CRASHES = StereoParams(sgbm=SGBMParams(mode="sgbm_3way", uniqueness_ratio=100, num_disparities=64))


def job(params, origin="/etc/uav-depth/params.yaml"):
    return Job(params, origin, RangingConfig(), CALIB, ROI)


def test_an_opencv_crash_refuses_the_parameters_with_the_signal_and_this_process_lives():
    trials = Trials()
    try:
        assert trials.run(job(GOOD)).why is None
        with pytest.raises(ConfigError) as info:
            trials.run(job(CRASHES))
        assert str(info.value) == ("/etc/uav-depth/params.yaml: (parameters) must run the test render without "
                                   "crashing (tried in a child process), but got 'OpenCV crashed with SIGFPE on the "
                                   "test render'")
        assert trials.run(job(GOOD)).why is None       # a new child for the next trial
        assert trials.started == 2
    finally:
        trials.close()


def test_a_trial_that_does_not_answer_within_its_bound_is_killed_and_refused():
    trials = Trials(timeout_s=0.01)        # Python alone takes longer to start
    try:
        with pytest.raises(ConfigError, match=r"but got 'the test render did not finish within 0\.01 s \(the child "
                                              r"was killed\)'"):
            trials.run(job(GOOD))
        assert trials._proc is None
    finally:
        trials.close()


def test_one_child_answers_a_burst_of_trials_and_runs_below_the_callers_priority():
    trials = Trials()
    try:
        for _ in range(3):
            assert trials.run(job(GOOD)).why is None
        assert trials.started == 1
        child = trials._proc.pid
        assert os.getpriority(os.PRIO_PROCESS, child) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + 10)
    finally:
        trials.close()
    assert trials._proc is None


def _config(rx, params_file):
    return run_config_from_dict({
        "source": {"kind": "synthetic", "fps": 10, "scene": {"width": 320, "height": 240, "focal_px": 200.0,
                                                             "branch_distance_m": 0.8, "seed": 1}},
        "params_file": str(params_file), "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 20},
        "ranging": {"max_age_ms": 499},
        "service": {"frame_timeout_s": 10.0, "params_poll_s": 0.1, "status_interval_s": 0.5}}, sources=SOURCES)


def test_a_reload_that_crashes_opencv_is_refused_and_the_daemon_flies_on(rx, tmp_path, monkeypatch):
    path = tmp_path / "params.yaml"
    save_params(GOOD, path)
    svc = Service(_config(rx, path))
    stop = threading.Event()
    runner = threading.Thread(target=svc.run, args=(stop,), daemon=True)
    runner.start()
    try:
        assert rx.wait(lambda: svc.stats.frames >= 3, 120), "never measured"
        # The one seam: the parameter file now yields what OpenCV cannot take.
        real = stage_module.load_params
        monkeypatch.setattr(stage_module, "load_params", lambda p: CRASHES if p == path else real(p))
        save_params(GOOD.replace(**{"sgbm.uniqueness_ratio": 11}), path)
        kept = f"uav-depth: params rejected, kept {GOOD.hash()[:8]}"
        assert rx.wait(lambda: kept in rx.texts(), 120), rx.texts()
        assert "OpenCV crashed with SIGFPE on the test render" in svc.stages.rejected
        assert svc.stage.params == GOOD
        t = time.monotonic()
        assert rx.wait(lambda: len([m for m in rx.of("DISTANCE_SENSOR", since=t) if m.signal_quality > 1]) >= 10,
                       120), "the readings stopped"
        assert rx.texts().count(kept) == 1
    finally:
        stop.set()
        runner.join(30)
    assert not runner.is_alive()
    assert svc.stages.trials._proc is None       # shutdown ended the child


def test_parameters_that_crash_opencv_at_start_up_fail_it_with_one_error(rx, tmp_path, monkeypatch):
    path = tmp_path / "params.yaml"
    save_params(GOOD, path)
    monkeypatch.setattr(stage_module, "load_params", lambda p: CRASHES)      # the one seam, as above
    svc = Service(_config(rx, path))
    with pytest.raises(ConfigError, match=r"params\.yaml: \(parameters\) must run the test render without crashing "
                                          r"\(tried in a child process\), but got 'OpenCV crashed with SIGFPE"):
        svc.run(threading.Event())
    assert svc.stages.trials._proc is None
