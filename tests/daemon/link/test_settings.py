"""The autopilot's settings against the range on the wire: the rules, the command that prints them, and the
running daemon reading them back from a pymavlink autopilot that answers PARAM_VALUE (issue 47 item 2)."""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from uav_depth.daemon.link.settings import ARDUPILOT, PX4, WireRange, misfits, recommended
from uav_depth.daemon.link.vocabulary import mavutil

from mavlink_peer import free_port

ROOT = Path(__file__).resolve().parents[3]
SITL_YAML = ROOT / "deploy" / "examples" / "sitl.yaml"
#: What the 640x360 flight file states on the wire (uav-depth autopilot-params --config deploy/examples/sitl.yaml).
RANGE = WireRange(min_cm=23, max_cm=348, orientation=0)
#: The walk-through's settings before this check existed: RNGFND1_MIN 0.3 above the daemon's 0.23 m.
WALKTHROUGH = {"RNGFND1_TYPE": 10, "PRX1_TYPE": 2, "AVOID_ENABLE": 2, "AVOID_MARGIN": 1.5, "AVOID_BEHAVE": 1,
               "PRX_FILT": 0, "RNGFND1_ORIENT": 0, "RNGFND1_MIN": 0.3, "RNGFND1_MAX": 7, "PRX1_MIN": 0,
               "PRX1_MAX": 0}


def test_the_old_walkthrough_minimum_does_not_fit_and_nothing_else_is_flagged():
    lines = misfits(ARDUPILOT, WALKTHROUGH, RANGE)
    assert lines == ["RNGFND1_MIN is 0.3; it must be at or below the daemon's min_distance 0.23 m: nearer readings "
                     "read as out of range low (clear)"]


@pytest.mark.parametrize("param,value", [("RNGFND1_ORIENT", 25), ("RNGFND1_MAX", 3.0), ("PRX1_MIN", 0.3),
                                         ("PRX1_MAX", 3.0), ("AVOID_ENABLE", 1), ("AVOID_MARGIN", 0.24),
                                         ("AVOID_MARGIN", 3.5), ("PRX_FILT", 0.25), ("PRX1_TYPE", 0)])
def test_each_ardupilot_rule_flags_its_parameter(param, value):
    fitting = {**WALKTHROUGH, "RNGFND1_MIN": 0.2}
    assert misfits(ARDUPILOT, fitting, RANGE) == []
    lines = misfits(ARDUPILOT, {**fitting, param: value}, RANGE)
    assert len(lines) == 1 and lines[0].startswith(f"{param} is {value:g}; it must be"), lines


def test_rangefinder_limits_do_not_apply_without_the_mavlink_rangefinder():
    values = {**WALKTHROUGH, "RNGFND1_TYPE": 0}              # proximity only: RNGFND1_MIN is not used
    assert misfits(ARDUPILOT, values, RANGE) == []
    assert misfits(ARDUPILOT, {**values, "PRX1_TYPE": 4}, RANGE)[0].startswith("RNGFND1_TYPE is 0")


@pytest.mark.parametrize("rules", [ARDUPILOT, PX4], ids=["ardupilot", "px4"])
def test_what_the_command_recommends_fits(rules):
    values = {rule.param: value for rule, value, _ in recommended(rules, RANGE)}
    assert misfits(rules, values, RANGE) == []


def test_px4_collision_prevention_distance():
    assert misfits(PX4, {"CP_DIST": 1.5, "CP_GO_NO_DATA": 0}, RANGE) == []
    assert [line.split(";")[0] for line in misfits(PX4, {"CP_DIST": 0.2, "CP_GO_NO_DATA": 1}, RANGE)] == [
        "CP_DIST is 0.2", "CP_GO_NO_DATA is 1"]
    assert misfits(PX4, {"CP_DIST": -1}, RANGE)                      # collision prevention off


def test_autopilot_params_prints_the_values_for_the_640x360_flight_file():
    out = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "autopilot-params", "--config", str(SITL_YAML)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    sets = dict(line.split("#")[0].split()[2:4] for line in out.stdout.splitlines() if line.startswith("param set"))
    assert sets["RNGFND1_MIN"] == "0.23" and sets["RNGFND1_MAX"] == "3.48" and sets["RNGFND1_ORIENT"] == "0"
    assert misfits(ARDUPILOT, {k: float(v) for k, v in sets.items()}, RANGE) == []
    assert "min_distance 23 cm, max_distance 348 cm" in out.stdout.splitlines()[0]


class ParamAutopilot:
    """ArduPilot as the daemon sees it: HEARTBEAT at 1 Hz, PARAM_VALUE for each PARAM_REQUEST_READ of a
    parameter it has (none for one it lacks), the daemon's STATUSTEXT and first message recorded."""

    def __init__(self, port, params):
        self.conn = mavutil().mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        self.params = params
        self.asked: list[str] = []
        self.texts: list[tuple[float, str]] = []
        self.first_heard: float | None = None
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _loop(self):
        mav = self.conn.mav
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                mav.heartbeat_send(2, 3, 0, 0, 4)                 # quadrotor, ArduPilot, active
                next_hb = now + 1.0
            m = self.conn.recv_match(blocking=True, timeout=0.02)
            if m is None or m.get_type() == "BAD_DATA":
                continue
            if self.first_heard is None:
                self.first_heard = time.monotonic()
            if m.get_type() == "STATUSTEXT":
                self.texts.append((time.monotonic(), m.text))
            elif m.get_type() == "PARAM_REQUEST_READ":
                name = m.param_id.rstrip("\x00")
                self.asked.append(name)
                if name in self.params:
                    mav.param_value_send(name.encode(), float(self.params[name]), 9, len(self.params), 0)

    def close(self):
        self._stop.set()
        self._t.join(1)
        self.conn.close()


def test_the_daemon_reports_a_mismatched_rngfnd1_min_within_5_s_of_connecting(tmp_path):
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(SITL_YAML),
                             "--mavlink-url", f"udpin:127.0.0.1:{port}"], stdout=subprocess.DEVNULL,
                            stderr=open(tmp_path / "stderr", "w"), env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    log = lambda: (tmp_path / "stderr").read_text()  # noqa: E731
    ap = None
    try:
        deadline = time.monotonic() + 120
        while "ready:" not in log():
            assert proc.poll() is None and time.monotonic() < deadline, log()[-2000:]
            time.sleep(0.1)
        ap = ParamAutopilot(port, WALKTHROUGH)
        deadline = time.monotonic() + 30
        while not any("check" in text for _, text in ap.texts) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        proc.terminate()
        proc.wait(20)
        if ap is not None:
            ap.close()
    said = [(t, text) for t, text in ap.texts if "check" in text]
    assert said, (ap.texts, log()[-2000:])
    t_said, text = said[0]
    assert text == "uav-depth: check RNGFND1_MIN 0.3"
    assert t_said - ap.first_heard <= 5.0, f"reported {t_said - ap.first_heard:.1f} s after connecting"
    assert {"RNGFND1_MIN", "RNGFND1_MAX", "RNGFND1_ORIENT", "PRX1_TYPE", "AVOID_MARGIN"} <= set(ap.asked)
    assert ("autopilot setting does not fit the range on the wire (0.23..3.48 m): RNGFND1_MIN is 0.3; it must be "
            "at or below the daemon's min_distance 0.23 m") in log()
    assert len(said) == 1
    print(f"\nRNGFND1_MIN 0.3 reported {t_said - ap.first_heard:.2f} s after connecting")


def test_sitl_reports_it_while_still_waiting_for_the_pose(tmp_path):
    # uav-depth sitl starts the service only once the autopilot's pose comes (about 40 s after ArduPilot
    # boots); the settings are checked when the autopilot is first heard
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config", str(SITL_YAML),
                             "--mavlink-url", f"udpin:127.0.0.1:{port}", "--truth-log", str(tmp_path / "t.csv")],
                            stdout=subprocess.DEVNULL, stderr=open(tmp_path / "stderr", "w"))
    log = lambda: (tmp_path / "stderr").read_text()  # noqa: E731
    ap = None
    try:
        deadline = time.monotonic() + 120
        while "waiting as long as it takes" not in log():
            assert proc.poll() is None and time.monotonic() < deadline, log()[-2000:]
            time.sleep(0.1)
        ap = ParamAutopilot(port, WALKTHROUGH)            # HEARTBEAT and parameters, never a pose
        deadline = time.monotonic() + 30
        while not any("check" in text for _, text in ap.texts) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        proc.terminate()
        proc.wait(20)
        if ap is not None:
            ap.close()
    said = [(t, text) for t, text in ap.texts if "check" in text]
    assert [text for _, text in said] == ["uav-depth: check RNGFND1_MIN 0.3"], (ap.texts, log()[-2000:])
    assert said[0][0] - ap.first_heard <= 5.0
    assert "ready:" not in log()                           # said before the service (and its clock) started


def test_one_check_per_link_whoever_starts_it():
    from uav_depth.daemon.config import MavlinkConfig
    from uav_depth.daemon.link.endpoint import MavlinkLink
    from uav_depth.daemon.link.settings_check import attach

    link = MavlinkLink(MavlinkConfig(url=f"udpin:127.0.0.1:{free_port()}"))
    first = attach(link, lambda: RANGE)
    later = WireRange(30, 300, 0)
    assert attach(link, lambda: later) is first and first.wire_range() == later
