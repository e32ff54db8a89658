"""OBSTACLE_DISTANCE: a synthetic scene with posts at known bearings and ranges, through the real pipeline
(the cheap full-width pass) and the real daemon, decoded with pymavlink."""

import math
import socket
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import yaml

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.core.session import SessionWriter
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.daemon.link.vocabulary import mavutil
from uav_depth.daemon.obstacles import (N_SECTORS, UINT16_UNKNOWN, Field, ObstacleConfig, ObstacleSender, bins_cm,
                                        encoder, limits_cm, sector_ranges)

W, H, F, B = 640, 360, 350.0, 0.063
CX = (W - 1) / 2
BACKGROUND_M = 12.0
#: (bearing deg, FRD clockwise +; horizontal range m; width m)
POSTS = [(-20.0, 2.0, 0.3), (0.0, 3.5, 0.3), (25.0, 1.5, 0.25)]


def render_posts(posts=POSTS, seed=0):
    """Left/right images of textured fronto-parallel plates over a far textured wall, exact by construction."""
    rng = np.random.default_rng(seed)
    xs = np.arange(W, dtype=np.float32)
    left = np.zeros((H, W), np.float32)
    right = np.zeros((H, W), np.float32)
    layers = [(BACKGROUND_M, -1e9, 1e9)]
    for bearing, r, width in posts:
        z = r * math.cos(math.radians(bearing))
        x = r * math.sin(math.radians(bearing))
        layers.append((z, CX + F * (x - width / 2) / z, CX + F * (x + width / 2) / z))
    for z, x0, x1 in sorted(layers, key=lambda l: -l[0]):      # far to near: nearer layers occlude
        tex = cv2.GaussianBlur(rng.uniform(0, 255, (H, W + 200)).astype(np.float32), (0, 0), 1.2)
        d = F * B / z
        in_left = (xs >= x0) & (xs < x1)
        left[:, in_left] = tex[:, :W][:, in_left]
        src = xs + d                                            # right pixel x sees left pixel x + d
        map_x = np.repeat(src[None, :], H, 0)
        map_y = np.repeat(np.arange(H, dtype=np.float32)[:, None], W, 1)
        warped = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR)
        in_right = (src >= x0) & (src < x1)
        right[:, in_right] = warped[:, in_right]
    noise = lambda: rng.normal(0, 1.5, (H, W))  # noqa: E731
    return [np.clip(i + noise(), 0, 255).astype(np.uint8) for i in (left, right)]


FIELD = Field(W, F, CX)


def expected_sector(bearing):
    return int((bearing - FIELD.left_deg) / FIELD.increment_deg)


def test_field_geometry_follows_the_autopilots_conventions():
    hfov = 2 * math.degrees(math.atan2(W / 2, F))
    assert FIELD.increment_deg * N_SECTORS == pytest.approx(hfov, abs=1e-6)
    assert FIELD.angle_offset_deg == pytest.approx(-hfov / 2 + FIELD.increment_deg / 2)   # centre of element 0
    cols = FIELD.sector_of_column()
    assert cols[0] == 0 and cols[-1] == N_SECTORS - 1 and np.all(np.diff(cols) >= 0)
    # element j's centre (what ArduPilot and PX4 take as its bearing) is where its columns are
    for j in (0, 20, 36, 71):
        x = CX + F * math.tan(math.radians(FIELD.centre_deg(j)))
        assert cols[int(round(min(max(x, 0), W - 1)))] == j


def test_bins_never_zero_never_clear_when_blind():
    ranges = np.array([0.05, 1.234, 9.0, np.nan] + [1.0] * 68)
    confident = np.array([True, True, True, True] + [False] * 68)
    out = bins_cm(ranges, confident, 20, 700)
    assert out[:4] == [21, 123, 701, UINT16_UNKNOWN]       # too close -> min+1; far -> max+1; nothing -> unknown
    assert set(out[4:]) == {UINT16_UNKNOWN} and 0 not in out
    assert limits_cm(0.2, 7.0) == (19, 700)          # as DISTANCE_SENSOR: the minimum rounded down, less 1


#: flying parameters for 640x360 (search range 64: 0.34 m .. far); the pass matches at half resolution
FLY = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})


def _sender(sent, params=FLY):
    return ObstacleSender(ObstacleConfig(enabled=True, scale=0.5), FIELD, F * B, 0.5, lambda: params,
                          lambda: (20, 700), sent.append, t_start=0.0, clock=lambda: 1.0)


def test_posts_at_known_bearings_within_one_sector_and_5_percent():
    left, right = render_posts()
    report = _sender([]).compute(left, right, t_capture=0.9)
    assert report is not None
    d = np.array(report.distances)
    for bearing, r, width in POSTS:
        j = expected_sector(bearing)
        near = d[max(0, j - 1):j + 2]
        hit = near[(near < 701)]
        assert hit.size, (bearing, near)
        assert abs(hit.min() / 100 - r) <= 0.05 * r, (bearing, r, near)
    # the wall at 12 m is beyond max 7 m: clear (max + 1) where no post is, never a made-up obstacle;
    # the band at the left edge that SGBM cannot match is unknown, never clear
    half = lambda r, w: math.degrees(math.atan2(w / 2, r))  # noqa: E731  a post's angular half-width
    post_sectors = {s for b, r, w in POSTS
                    for s in range(expected_sector(b - half(r, w)) - 1, expected_sector(b + half(r, w)) + 2)}
    others = [d[j] for j in range(N_SECTORS) if j not in post_sectors]
    assert sum(v == 701 for v in others) >= 0.75 * len(others), others
    assert all(v == 701 or v == UINT16_UNKNOWN for v in others)
    assert d[0] == UINT16_UNKNOWN


def test_a_blind_frame_sends_nothing_and_a_stale_one_neither():
    flat = np.full((H, W), 100, np.uint8)
    assert _sender([]).compute(flat, flat, t_capture=0.9) is None
    left, right = render_posts()
    assert _sender([]).compute(left, right, t_capture=0.2) is None     # 0.8 s old once computed: > 0.5 s


def test_pymavlink_decodes_what_is_sent():
    left, right = render_posts()
    report = _sender([]).compute(left, right, t_capture=0.9)
    mav = mavutil().mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    buf = encoder(report, 4)(mav).pack(mav)
    msg = mavutil().mavlink.MAVLink(None).decode(bytearray(buf))
    assert msg.get_type() == "OBSTACLE_DISTANCE"
    assert list(msg.distances) == report.distances and msg.frame == 12
    assert msg.increment_f == pytest.approx(FIELD.increment_deg, rel=1e-6)
    assert msg.increment == round(FIELD.increment_deg) and msg.angle_offset == pytest.approx(FIELD.angle_offset_deg)
    assert (msg.min_distance, msg.max_distance) == (20, 700)


def test_off_by_default_and_keys_checked(tmp_path):
    cfg = run_config_from_dict({"source": {"kind": "replay", "path": str(tmp_path)}})
    assert cfg.obstacle_distance.enabled is False
    with pytest.raises(ConfigError, match=r"obstacle_distance.scale.*between"):
        run_config_from_dict({"source": {"kind": "replay", "path": str(tmp_path)},
                              "obstacle_distance": {"scale": 2}})


def test_daemon_sends_it_beside_distance_sensor(tmp_path, rx):
    left, right = render_posts()
    w = SessionWriter(tmp_path / "session", Calibration(focal_px=F, baseline_m=B, width=W, height=H))
    for i in range(3):
        w.write(i, left, right, meta={"time_s": i * 0.2})
    params = tmp_path / "params.yaml"
    save_params(FLY.replace(**{"wls.enabled": False}), params)
    config = {"source": {"kind": "replay", "path": str(tmp_path / "session"), "rate_hz": 3, "loop": True},
              "params_file": str(params),
              # On the 25 deg post (1.5 m away, z = 1.36 m): the central third holds only a sliver of the -20 deg one,
              # "no measurement" (quality 18). Before 2026-12-05 the near pass, without a left-right check when WLS
              # is off, read every region of this scene as too close, and that is what went out.
              "ranging": {"max_age_ms": 499, "max_distance_m": 7.0, "roi": [455, 140, 510, 220]},
              "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 10},
              "obstacle_distance": {"enabled": True, "rate_hz": 2}}
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(config))
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(tmp_path / "run.yaml")],
                            stdout=subprocess.DEVNULL, stderr=open(tmp_path / "stderr", "w"))
    try:
        msgs = rx.wait_for("OBSTACLE_DISTANCE", timeout=120, count=2)
        ds = rx.wait_for("DISTANCE_SENSOR", timeout=30)
        z = 1.5 * math.cos(math.radians(25.0))
        assert all(abs(m.current_distance / 100 - z) <= 0.03 * z for m in ds), [m.current_distance for m in ds]
    finally:
        proc.terminate()
        code = proc.wait(20)
    assert code == 0, (tmp_path / "stderr").read_text()[-2000:]
    for msg in msgs:
        d = np.array(msg.distances)
        assert msg.frame == 12 and msg.max_distance == 700
        for bearing, r, width in POSTS:
            j = expected_sector(bearing)
            hit = d[max(0, j - 1):j + 2]
            hit = hit[hit < 701]
            assert hit.size and abs(hit.min() / 100 - r) <= 0.05 * r, (bearing, r, d[j - 1:j + 2])
