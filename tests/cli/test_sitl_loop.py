"""The closed loop: a test vehicle on loopback flies the real ``uav-depth sitl`` process toward the tree.

The vehicle is a pymavlink endpoint acting as an autopilot (system 1, component 1, like
ArduPilot SITL's ``--serial1 udpclient:``): HEARTBEAT at 1 Hz, LOCAL_POSITION_NED and
ATTITUDE at the rate the daemon asks for with MAV_CMD_SET_MESSAGE_INTERVAL, along a
scripted path toward a tree at a fixed NED position, and it listens for DISTANCE_SENSOR.
Its own geometry is the ground truth: flying level along north, the distance from the
camera to the branch's nearest surface is tree_north - north.
"""

from __future__ import annotations

import csv
import os
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

import pytest
import yaml

from uav_depth.core.params.flight import flight_params
from uav_depth.core.params import save_params
from uav_depth.daemon.link.vocabulary import mavutil
from uav_depth.core.ranging import RangingConfig

TREE_NED = (3.0, 0.0, -2.0)
RATE_HZ = 20.0
POSE_RATE_HZ = 30.0
MAX_AGE_MS = 450.0
POSE_TIMEOUT_S = 0.3
HOVER_S = 2.5
SPEED_MPS = 0.3
#: (distance to the branch, m) of each hover stop; the vehicle flies between them at SPEED_MPS.
STOPS = (2.0, 1.4, 1.0, 0.6)
#: The daemon's default minimum signal quality: readings at or above it are held to 5% both ways.
FLOOR = RangingConfig().min_quality


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Path:
    """Distance to the branch over time: hover, fly, hover, ... (level, heading north)."""

    def __init__(self, stops=STOPS, hover_s=HOVER_S, speed=SPEED_MPS):
        self.segments = []      # (t0, t1, d0, d1)
        t = 0.0
        for i, d in enumerate(stops):
            self.segments.append((t, t + hover_s, d, d))
            t += hover_s
            if i + 1 < len(stops):
                dt = abs(stops[i + 1] - d) / speed
                self.segments.append((t, t + dt, d, stops[i + 1]))
                t += dt
        self.duration = t

    def distance(self, t: float) -> float:
        for t0, t1, d0, d1 in self.segments:
            if t <= t1:
                return d0 if t1 == t0 else d0 + (d1 - d0) * max(0.0, t - t0) / (t1 - t0)
        return self.segments[-1][3]

    def hovers(self):
        return [(t0, t1, d0) for t0, t1, d0, d1 in self.segments if d0 == d1]


@dataclass
class Vehicle:
    """A minimal autopilot on loopback. ``start_flight()`` starts the path clock."""

    port: int
    path: Path
    conn: object = None
    intervals: dict = field(default_factory=dict)           # msg id -> requested interval, us
    readings: list = field(default_factory=list)            # (t, msg) of DISTANCE_SENSOR
    t_flight: float | None = None
    quiet: bool = False                                      # stop sending poses (autopilot gone)

    def __post_init__(self):
        self.conn = mavutil().mavlink_connection(f"udpout:127.0.0.1:{self.port}", source_system=1,
                                                 source_component=1)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def north(self, now: float) -> float:
        t = 0.0 if self.t_flight is None else now - self.t_flight
        return TREE_NED[0] - self.path.distance(t)

    def truth_range(self, t_from: float, t_to: float) -> tuple[float, float]:
        """Min and max true distance over [t_from, t_to] (vehicle clock, monotonic s)."""
        ds = [TREE_NED[0] - self.north(t_from + (t_to - t_from) * k / 20.0) for k in range(21)]
        return min(ds), max(ds)

    def _loop(self):
        mav = self.conn.mav
        t0 = time.monotonic()
        next_hb = next_pose = t0
        while not self.stop.is_set():
            now = time.monotonic()
            boot_ms = int((now - t0) * 1000)
            if now >= next_hb:
                mav.heartbeat_send(2, 3, 81, 0, 4)           # quadrotor, ArduPilot, armed guided, active
                next_hb += 1.0
            period = self.intervals.get(32, 1e5) / 1e6     # 10 Hz until asked for more
            if now >= next_pose and not self.quiet:
                n = self.north(now)
                mav.local_position_ned_send(boot_ms, n, TREE_NED[1], TREE_NED[2], 0.0, 0.0, 0.0)
                mav.attitude_send(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                next_pose = now + period
            while True:
                msg = self.conn.recv_match(blocking=False)
                if msg is None:
                    break
                kind = msg.get_type()
                if kind == "DISTANCE_SENSOR":
                    self.readings.append((time.monotonic(), msg))
                elif kind == "COMMAND_LONG" and msg.command == 511:
                    self.intervals[int(msg.param1)] = msg.param2
                    mav.command_ack_send(511, 0)
            time.sleep(0.002)


def valid(msg) -> bool:
    return msg.signal_quality > 1 and msg.min_distance <= msg.current_distance <= msg.max_distance


@pytest.fixture
def flight(tmp_path):
    port = free_udp_port()
    # The flight parameters for this camera (half scale, centre third): a frame stays well inside
    # max_age_ms on two loaded cores, where the full-resolution defaults took up to a second.
    save_params(flight_params(focal_px=375.0, baseline_m=0.063), tmp_path / "params.yaml")
    config = {
        "params_file": "params.yaml",
        # 480x270 keeps a frame (render + SGBM + WLS) near 0.2 s on two shared cores.
        "source": {"kind": "synthetic", "fps": 5,
                   "scene": {"width": 480, "height": 270, "focal_px": 375.0, "baseline_m": 0.063,
                             "branch_distance_m": 2.5, "n_branches": 0, "seed": 5}},
        "ranging": {"max_age_ms": MAX_AGE_MS, "max_distance_m": 6.0, "min_quality": 5},   # a plain scene scores 10 at 2 m: see FLOOR
        "mavlink": {"url": f"udpin:127.0.0.1:{port}", "rate_hz": RATE_HZ, "component_id": 191},
        "service": {"first_frame_timeout_s": 30},
    }
    (tmp_path / "sitl.yaml").write_text(yaml.safe_dump(config))
    vehicle = Vehicle(port, Path())
    cmd = [sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config", str(tmp_path / "sitl.yaml"),
           "--tree-ned", *map(str, TREE_NED), "--pose-rate-hz", str(POSE_RATE_HZ), "--pose-timeout-s", str(POSE_TIMEOUT_S),
           "--truth-log", str(tmp_path / "truth.csv"), "--wait-s", "30"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    vehicle.thread.start()
    try:
        yield vehicle, proc, tmp_path
    finally:
        vehicle.stop.set()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        vehicle.conn.close()


def test_distance_sensor_tracks_the_approach(flight):
    vehicle, proc, tmp_path = flight
    # Hover at the first stop until the daemon measures (start-up: imports, scene build, first frame).
    deadline = time.monotonic() + 40
    while not any(valid(m) for _, m in vehicle.readings) and time.monotonic() < deadline:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.05)
    if not any(valid(m) for _, m in vehicle.readings):
        proc.send_signal(signal.SIGTERM)
        raise AssertionError("no valid DISTANCE_SENSOR within 40 s: " + proc.communicate(timeout=30)[0][-3000:])
    t_fly = time.monotonic()
    vehicle.t_flight = t_fly
    time.sleep(vehicle.path.duration + 0.3)
    t_end = time.monotonic()
    # The autopilot goes quiet: its last pose ages out and the daemon must stop reporting a distance.
    vehicle.quiet = True
    time.sleep(2.0)
    t_quiet_end = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out[-3000:]

    # It asked for the pose it needs, at the rate it was told to.
    want_us = 1e6 / POSE_RATE_HZ
    assert vehicle.intervals.get(32) == pytest.approx(want_us, rel=1e-3), vehicle.intervals
    assert vehicle.intervals.get(30) == pytest.approx(want_us, rel=1e-3), vehicle.intervals

    flight_readings = [(t, m) for t, m in vehicle.readings if t_fly <= t <= t_end]
    # Each estimate as soon as it exists: the stereo rate (5 frames/s here), capped at rate_hz.
    rate = len(flight_readings) / (t_end - t_fly)
    assert 2.0 <= rate <= RATE_HZ * 1.1, f"{rate:.1f} Hz"
    m0 = flight_readings[0][1]
    assert (m0.get_srcSystem(), m0.get_srcComponent()) != (1, 1) and m0.orientation == 0

    # Every valid reading matches the truth at some instant it may stem from: the daemon never
    # sends an estimate older than max_age_ms (from the frame's render), and never renders a
    # pose older than --pose-timeout-s (from its arrival); 0.1 s for the trip over loopback.
    # Within 5% both ways where the default floor would send the reading (signal quality >= FLOOR);
    # below it (sent here only because the test lowers min_quality to see the loop at 2 m), never
    # farther than 5%: there the near quantile of a small, noisy object reads up to 8% nearer (offline,
    # 5 of 123 frames at 1.60-2.00 m, quality 11-15; none farther than 2%), which is why the floor exists.
    window = MAX_AGE_MS / 1000.0 + POSE_TIMEOUT_S + 0.1
    off = []
    for t, m in flight_readings:
        if not valid(m):
            continue
        lo, hi = vehicle.truth_range(t - window, t)
        d = m.current_distance / 100.0
        near_ok = d >= 0.95 * lo - 0.01 or m.signal_quality < FLOOR      # 1 cm: DISTANCE_SENSOR is in whole cm
        if not (near_ok and d <= 1.05 * hi + 0.01):
            off.append((round(t - t_fly, 2), d, round(lo, 3), round(hi, 3), m.signal_quality))
    assert not off, f"readings off the truth by more than 5% (t, measured, truth range, quality): {off[:10]}"
    # ... and the approach is covered: valid readings at every hover stop, their median within 5% there.
    for h0, h1, dist in vehicle.path.hovers():
        settled = [m.current_distance / 100.0 for t, m in flight_readings
                   if t_fly + h0 + window <= t <= t_fly + h1 and valid(m)]
        assert len(settled) >= 3, f"only {len(settled)} valid readings while hovering {dist} m from the branch"
        assert statistics.median(settled) == pytest.approx(dist, rel=0.05, abs=0.01), (dist, settled)

    # With the autopilot silent, no distance once its last pose is stale (pose timeout + max age).
    quiet = [m for t, m in vehicle.readings if t_end + POSE_TIMEOUT_S + MAX_AGE_MS / 1000.0 + 0.2 <= t <= t_quiet_end]
    assert not quiet, f"blind without a fresh pose: nothing may be sent, got {[m.current_distance for m in quiet][:5]}"

    # The truth log: the rendered truth matches the vehicle's geometry, the measurement the truth.
    with open(tmp_path / "truth.csv") as f:
        rows = list(csv.DictReader(f))
    posed = [r for r in rows if r["north_m"] and r["truth_m"]]
    assert len(posed) >= 20, len(rows)
    for r in posed:
        assert float(r["truth_m"]) == pytest.approx(TREE_NED[0] - float(r["north_m"]), rel=0.005)
    measured = [abs(float(r["error_pct"])) for r in posed if r["error_pct"]]
    assert len(measured) >= 0.8 * len(posed)
    measured.sort()
    assert measured[len(measured) // 2] < 2.0 and measured[int(0.9 * len(measured))] < 5.0, measured
    print(f"\nsitl loop: {len(flight_readings)} DISTANCE_SENSOR in {t_end - t_fly:.1f} s ({rate:.1f} Hz), "
          f"{sum(valid(m) for _, m in flight_readings)} valid; truth log {len(posed)} frames, "
          f"|error| median {measured[len(measured) // 2]:.2f} %, max {measured[-1]:.2f} %")
