"""uav-depth sitl as a user runs it: bad settings, --check, and --scripted without an autopilot."""

from __future__ import annotations

import csv
import signal
import socket
import statistics
import subprocess
import sys
import time

import pytest
import yaml

from uav_depth.core.params.flight import flight_params
from uav_depth.cli.exit_codes import EXIT_CONFIG
from uav_depth.core.params import save_params
from uav_depth.daemon.link.vocabulary import mavutil


def sitl(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "sitl", *args], capture_output=True,
                          text=True, timeout=timeout)


def write_config(path, **source):
    # The flight parameters for this camera: a frame in a fraction of the defaults' time (two loaded cores).
    save_params(flight_params(focal_px=375.0, baseline_m=0.063), path.with_name("params.yaml"))
    cfg = {"params_file": "params.yaml",
           "source": {"kind": "synthetic", "fps": 5,
                      # 480 px wide: the default 128-px disparity search leaves the central ROI matchable.
                      "scene": {"width": 480, "height": 270, "focal_px": 375.0, "branch_distance_m": 1.5,
                                "n_branches": 0, "seed": 4}, **source},
           # 499 ms (the most allowed): a frame can take 0.5 s on two loaded cores.
           "ranging": {"max_age_ms": 499, "min_quality": 15},      # a plain scene: see test_sitl_blind
           "mavlink": {"url": "udpout:127.0.0.1:14999"}}
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.mark.parametrize("extra, message", [
    (["--camera-pitch-deg", "95"], "--camera-pitch-deg must be above -90 and below 90, but got 95.0"),
    (["--pose-rate-hz", "0"], "--pose-rate-hz must be between 1 and 200, but got 0.0"),
    (["--force-scripted"], "--force-scripted only goes with --scripted, but got True"),
    (["--wait-s", "-1"], "--wait-s must be between 0 (no limit) and 3600, but got -1.0"),
    (["--set", "source.kind=replay", "--set", "source.path=/nonexistent"], None),
], ids=["pitch", "rate", "force-alone", "wait", "not-synthetic"])
def test_bad_settings_exit_78_with_one_line(tmp_path, extra, message):
    cfg = write_config(tmp_path / "c.yaml")
    proc = sitl("--config", str(cfg), *extra, "--check")
    assert proc.returncode == EXIT_CONFIG, proc.stderr
    line = proc.stderr.strip()
    assert line.count("\n") == 0 and line.startswith("uav-depth sitl: error: ")
    if message:
        assert message in line
    else:
        assert "source" in line


def test_replay_source_is_refused(tmp_path):
    cfg = tmp_path / "c.yaml"
    session = tmp_path / "s"
    subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "synth", str(session), "--frames", "1",
                    "--width", "64", "--height", "48", "--focal-px", "50"], check=True, capture_output=True)
    cfg.write_text(yaml.safe_dump({"source": {"kind": "replay", "path": str(session)}}))
    proc = sitl("--config", str(cfg), "--check")
    assert proc.returncode == EXIT_CONFIG
    assert "source.kind must be synthetic for uav-depth sitl" in proc.stderr and "'replay'" in proc.stderr


def test_check_describes_the_simulation(tmp_path):
    cfg = write_config(tmp_path / "c.yaml")
    proc = sitl("--config", str(cfg), "--tree-ned", "5", "1", "-2", "--approach-yaw-deg", "90", "--check")
    assert proc.returncode == 0, proc.stderr
    assert "tree at NED [5.0, 1.0, -2.0] m, approached at heading 90 deg" in proc.stdout


def test_without_an_autopilot_the_scripted_approach_flies(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = write_config(tmp_path / "c.yaml", approach_speed_mps=0.2, stop_distance_m=0.8)
    listener = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config", str(cfg),
                             "--mavlink-url", f"udpout:127.0.0.1:{port}", "--scripted", "--listen-s", "0.5",
                             "--truth-log", str(tmp_path / "truth.csv")],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    readings = []
    try:
        deadline = time.monotonic() + 45
        while time.monotonic() < deadline and proc.poll() is None:
            msg = listener.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.5)
            if msg is not None and msg.signal_quality > 1:
                readings.append(msg.current_distance / 100.0)
                if len(readings) >= 8 and readings[-1] < 1.2:
                    break
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
        listener.close()
    assert proc.returncode == 0, out[-2000:]
    assert "scripted approach: listening 0.5 s for an autopilot's HEARTBEAT" in out
    assert readings, out[-2000:]
    # Every reading on the wire lies on the scripted path (1.5 m down to the 0.8 m stop), and it ends close.
    assert all(0.75 <= d <= 1.58 for d in readings) and readings[-1] < 1.2, readings
    with open(tmp_path / "truth.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and all(r["north_m"] == "" for r in rows)          # no autopilot pose to log
    # The rig moved along the script: the logged truth falls from the start (1.5 m) toward the stop (0.8 m),
    # never below it, at the scripted 0.2 m/s by the frames' own capture stamps (on loaded cores the first
    # frame may come late, so where it starts is not judged, only how it moves).
    truths = [float(r["truth_m"]) for r in rows if r["truth_m"]]
    assert truths[0] <= 1.5 and 0.79 <= min(truths) < 1.25, truths
    moving = [(float(r["time_s"]), float(r["truth_m"])) for r in rows if r["truth_m"] and float(r["truth_m"]) > 0.85]
    speeds = [(a - b) / (tb - ta) for (ta, a), (tb, b) in zip(moving, moving[1:]) if tb - ta > 0.1]
    assert speeds and 0.15 <= statistics.median(speeds) <= 0.25, (moving, speeds)
    assert all(b <= a + 1e-6 for a, b in zip(truths, truths[1:])), truths
    measured = [r for r in rows if r["error_pct"]]
    assert measured and all(abs(float(r["error_pct"])) < 5.0 for r in measured), [r["error_pct"] for r in measured]
