"""The live view: unit checks of its cost rules, and end to end in a real headless Chromium
against the real daemon process, reading the distance the page shows and the DISTANCE_SENSOR sent."""

import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
import yaml

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.daemon.liveview import LiveView, LiveViewConfig, Offer, colourise, render, wire_fields
from uav_depth.core.ranging import Measurement, RangeLimits
from uav_depth.daemon.estimate import Estimate

from daemon_process import missing_tool
from mavlink_peer import free_port

import socket


def _estimate(index=0, distance=1.5, bbox=(10, 10, 40, 30), t_capture=0.0):
    m = Measurement(distance, 0.01, 60, bbox, 8.4, 0.3, 500, 0.5)
    return Estimate(m, RangeLimits(0.1, 7.0, 0.5, 0.4), t_capture, t_capture + 0.1, index, "abcdef123456", 1.5,
                    {"latency": 100.0})


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def _view(clock, max_fps=5.0):
    return LiveView(LiveViewConfig(enabled=True, port=free_port(socket.SOCK_STREAM), max_fps=max_fps), 12.6,
                    lambda: {"state": "active", "fps": 9.5, "wire": None}, clock=clock)


def _offer(view, index):
    left = np.full((60, 80), 128, np.uint8)
    disp = np.full((60, 80), 8.0, np.float32)
    disp[:5] = np.nan
    view.offer(left, disp, _estimate(index), (20, 15, 60, 45), DEFAULT_PARAMS)


def test_nothing_is_encoded_while_nobody_asks():
    clock = FakeClock()
    view = _view(clock)
    assert view.jpeg() is None                      # no frame yet
    for i in range(50):
        _offer(view, i)
    assert view.encoded == 0


def test_encoding_is_rate_limited_and_cached_across_viewers():
    clock = FakeClock()
    view = _view(clock, max_fps=5.0)
    _offer(view, 1)
    first = view.jpeg()
    assert first[:2] == b"\xff\xd8" and view.encoded == 1
    _offer(view, 2)
    clock.t += 0.1                                  # sooner than 1/5 s: the cached picture
    assert view.jpeg() is first and view.encoded == 1
    clock.t += 0.15
    second = view.jpeg()
    assert view.encoded == 2 and second is not first
    clock.t += 1.0                                  # no new frame: nothing to redraw
    assert view.jpeg() is second and view.encoded == 2


def test_state_carries_the_frame_and_the_wire():
    clock = FakeClock()
    view = _view(clock)
    _offer(view, 7)
    clock.t = 0.25
    st = view.state()
    assert st["frame"]["distance_m"] == 1.5 and st["frame"]["index"] == 7 and st["frame"]["age_ms"] == 250.0
    assert st["wire"] == {"sent": False, "condition": "nothing yet", "valid": False}


def test_wire_fields_follow_the_send_clock_report():
    from uav_depth.daemon.link.contract import distance_report

    est = _estimate(t_capture=10.0)
    sent = wire_fields(distance_report(est, est.limits, 10.1, 0.5, 0.0))
    assert sent["sent"] and sent["valid"] and sent["current_distance"] == 150 and sent["condition"] == "measuring"
    stale = wire_fields(distance_report(est, est.limits, 12.0, 0.5, 0.0))
    assert not stale["sent"] and not stale["valid"] and "current_distance" not in stale


def test_picture_draws_region_box_and_colour_bar():
    disp = np.full((60, 80), 64.0, np.float32)
    disp[:, :10] = np.nan
    offer = Offer(np.zeros((60, 80), np.uint8), disp, _estimate(bbox=(10, 10, 40, 30)), (20, 15, 60, 45),
                  DEFAULT_PARAMS)
    pic = render(offer, 160, 12.6)
    assert pic.shape == (120 + 52, 320, 3)
    # the object's box is green on the left panel (left edge x 20, y 20..60 at scale 2)
    assert tuple(pic[40, 20]) == (60, 230, 60)
    # invalid disparity is black, valid is coloured
    assert pic[80, 165].sum() == 0 and pic[100, 300].sum() > 0
    assert colourise(np.array([[0.0, 128.0]], np.float32), 0, 128).shape == (1, 2, 3)


@pytest.mark.parametrize("section, key, value, rule", [
    ({"port": 0}, "liveview.port", "0", "between"),
    ({"enabled": "yes"}, "liveview.enabled", "yes", "true or false"),
    ({"max_fps": 100}, "liveview.max_fps", "100", "between"),
    ({"colour": 1}, "liveview.colour", "1", "not a known key"),
], ids=["port-0", "enabled-not-bool", "fps-too-high", "unknown-key"])
def test_bad_liveview_keys_name_key_rule_value(tmp_path, section, key, value, rule):
    with pytest.raises(ConfigError, match=rf"{re.escape(key)}.*{rule}") as err:
        run_config_from_dict({"source": {"kind": "replay", "path": str(tmp_path)}, "liveview": section})
    assert value in str(err.value)


def test_off_by_default_and_on_loopback():
    cfg = LiveViewConfig()
    assert cfg.enabled is False and cfg.host == "127.0.0.1"


def test_port_taken_is_a_config_error_naming_the_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    try:
        with pytest.raises(ConfigError, match=r"liveview.port"):
            LiveView.bind(LiveViewConfig(enabled=True, port=s.getsockname()[1]), 1.0, lambda: {})
    finally:
        s.close()


# -- end to end: the real daemon and a real browser --------------------------------------------

def chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if exe is None:
        missing_tool("Chromium is not installed (Debian: apt-get install chromium)")
    return exe


def browser_dom(url, budget_ms=2500):
    """The page's DOM after its script ran, from headless Chromium."""
    args = [chromium(), "--headless", "--disable-gpu", "--no-first-run", "--disable-extensions",
            f"--virtual-time-budget={budget_ms}", "--dump-dom", url]
    if os.geteuid() == 0:
        args.insert(1, "--no-sandbox")   # Chromium refuses to run its sandbox as root
    out = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def field(dom, ident):
    m = re.search(rf'id="{ident}"[^>]*>([^<]*)<', dom)
    assert m, f"{ident} not in the page: {dom[:400]}"
    return m.group(1).strip()


def test_browser_shows_the_distance_that_is_on_the_wire(tmp_path, rx):
    params = tmp_path / "params.yaml"
    # a light stage (no WLS): the daemon keeps its frames fresh on a loaded machine
    save_params(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64, "wls.enabled": False}), params)
    port = free_port(socket.SOCK_STREAM)
    config = {"source": {"kind": "synthetic", "fps": 5,
                         "scene": {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 1.2,
                                   "seed": 3}},
              "params_file": str(params), "ranging": {"max_age_ms": 499},
              "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 10},
              "liveview": {"enabled": True, "port": port, "max_fps": 2}}
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config))
    stderr = open(tmp_path / "daemon.stderr", "w")
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(path)],
                            stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        assert rx.wait(lambda: any(m.signal_quality > 1 for m in rx.of("DISTANCE_SENSOR")) or proc.poll() is not None,
                       timeout=90)
        assert proc.poll() is None, (tmp_path / "daemon.stderr").read_text()[-2000:]
        url = f"http://127.0.0.1:{port}/"
        with urllib.request.urlopen(url + "state.json", timeout=10) as r:
            assert json.load(r)["state"] == "active"
        shown = None
        for _ in range(6):   # a snapshot can catch a moment with nothing valid on the wire; look again
            dom = browser_dom(url)
            if field(dom, "wire-valid") == "a measurement":
                shown = dom
                break
        assert shown is not None, f"the page never showed a measurement on the wire: {dom[dom.find('<table'):dom.find('</table')]}"
        with urllib.request.urlopen(url + "frame.jpg", timeout=10) as r:
            assert r.headers["Content-Type"] == "image/jpeg" and r.read(2) == b"\xff\xd8"
        assert proc.poll() is None
    finally:
        proc.terminate()
        code = proc.wait(20)
        stderr.close()
    assert code == 0, (tmp_path / "daemon.stderr").read_text()[-2000:]
    sent = [m.current_distance for m in rx.of("DISTANCE_SENSOR") if m.signal_quality > 1]
    wire_cm = int(field(shown, "wire-distance-cm"))
    assert wire_cm in sent, (wire_cm, sorted(set(sent)))
    # a static branch: what the page says is what the autopilot got, to the centimetre
    values, counts = np.unique(sent, return_counts=True)
    assert abs(wire_cm - values[np.argmax(counts)]) <= 1
    measured_m = float(field(shown, "distance-m"))
    assert abs(measured_m * 100 - wire_cm) <= 1
    assert int(field(shown, "wire-quality")) in {m.signal_quality for m in rx.of("DISTANCE_SENSOR")}
    assert int(float(field(shown, "fps")) * 10) > 0
