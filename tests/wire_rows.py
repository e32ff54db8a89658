"""The wire contract's rows driven through the real daemon process, as a pymavlink peer receives them.

Each scenario starts ``uav-depth run`` (a real process; a synthetic or replay source;
config and files in a temporary directory) toward a :class:`mavlink_peer.Receiver` on
loopback and puts it into one or more :class:`~uav_depth.daemon.link.conditions.Condition`
from outside: the parameter file, the scene, the source's timing, the age limit, a
signal. Each condition gets a :class:`Window`: what arrived while the daemon was in it,
bounded by what arrived (its STATUSTEXT, HEARTBEATs) and by what the scenario did, never
by a fixed wait, so the scenarios hold on a loaded machine.

What a row expects is read from the contract, not copied: whether a DISTANCE_SENSOR goes
out (``Condition.sends``), the HEARTBEAT state and STATUSTEXT its row names
(``Condition.text.sent``, the text docs/wire.md's table is written from), otherwise the
STATUSTEXT the send clock says on entering it (``Condition.statustext``).

Used by tests/daemon/test_wire_conditions.py and bench/faults.py.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import yaml

from mavlink_peer import Receiver

from uav_depth.core.params import DEFAULT_PARAMS, dump_params
from uav_depth.daemon.link.clock import STATUSTEXT_MIN_S
from uav_depth.daemon.link.conditions import Condition
from uav_depth.daemon.link.vocabulary import BOOT_MS_MOD, HEARTBEAT_PERIOD_S, MAV_STATE, UINT8_UNKNOWN

#: Deadline for what a loaded machine takes its time over (never reached when things work).
PATIENCE_S = 180.0
SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 0.8, "branch_radius_m": 0.04,
         "seed": 1}
PARAMS_64 = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
GOOD = dump_params(PARAMS_64)
STATE_NAME = {code: name for name, code in MAV_STATE.items()}
MAX_AGE_MS = 450.0
#: How often the send clock looks at least (daemon/link/clock.py).
CLOCK_LOOK_S = 0.1


def config(port: int, params_file: Path | str | None, **sections) -> dict:
    """A run config toward a udpin peer on ``port``: synthetic 320x240 scene, max_age_ms 450 (generous on a
    loaded machine; the age rule has its own scenario)."""
    cfg = {"source": {"kind": "synthetic", "fps": 10, "scene": SCENE},
           "params_file": str(params_file) if params_file else None,
           "ranging": {"max_age_ms": MAX_AGE_MS},
           "mavlink": {"url": f"udpout:127.0.0.1:{port}", "rate_hz": 20},
           "service": {"shutdown_timeout_s": 3.0, "status_interval_s": 1.0, "params_poll_s": 0.2,
                       "first_frame_timeout_s": 120.0}}
    for key, value in sections.items():
        cfg[key] = {**cfg[key], **value} if key != "source" and isinstance(cfg.get(key), dict) else value
    return cfg


class Daemon:
    """``uav-depth run --config`` (or another command) as a real process, stderr kept in a file."""

    def __init__(self, workdir: Path, cfg: dict | None, *args: str, command: str = "run"):
        workdir.mkdir(parents=True, exist_ok=True)
        argv = [command, *args]
        if cfg is not None:
            path = workdir / "run.yaml"
            path.write_text(yaml.safe_dump(cfg))
            argv = [command, "--config", str(path), *args]
        self.stderr_path = workdir / f"stderr-{time.monotonic_ns()}.txt"
        with open(self.stderr_path, "w") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", *argv],
                                         stdout=subprocess.DEVNULL, stderr=err,
                                         env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
        self.t_start = time.monotonic()

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def wait_for(self, pred: Callable[[], object], what: str, timeout: float = PATIENCE_S):
        """``pred()``'s first true value; AssertionError with the daemon's last words if it exits or time runs out."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            got = pred()
            if got:
                return got
            if self.proc.poll() is not None:
                raise AssertionError(f"exited with {self.proc.returncode} waiting for {what}:\n{self.stderr()[-2000:]}")
            time.sleep(0.02)
        raise AssertionError(f"no {what} within {timeout:g} s:\n{self.stderr()[-2000:]}")

    def exit_code(self, timeout: float = PATIENCE_S) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"still running after {timeout:g} s:\n{self.stderr()[-2000:]}") from None

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 60.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.exit_code(timeout)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)


# -- what a row expects, read from the contract ------------------------------------------------------

_ROW_STATE = re.compile(r"HEARTBEAT\b[^;]*?\b(" + "|".join(n.upper() for n in MAV_STATE) + r")\b")
_ROW_TEXT = re.compile(r'STATUSTEXT "([^"]+)"')


@dataclass(frozen=True)
class Expected:
    """What the peer must receive in one condition."""

    sends: bool
    heartbeat: str
    texts: tuple[str, ...]

    def __str__(self) -> str:
        said = ", ".join(f'"{t}"' for t in self.texts)
        return f"{'DISTANCE_SENSOR' if self.sends else 'no DISTANCE_SENSOR'}; HEARTBEAT {self.heartbeat}; {said}"


def expected(cond: Condition) -> Expected:
    """The row of ``cond``: a HEARTBEAT state it names (else active), the STATUSTEXT it names (else the one
    the send clock says on entering it)."""
    row = cond.text.sent
    state = _ROW_STATE.search(row)
    texts = tuple(_ROW_TEXT.findall(row)) or (cond.statustext[0],)
    return Expected(cond.sends, state.group(1).lower() if state else "active", texts)


def reading_fits(cond: Condition, m) -> bool:
    """One DISTANCE_SENSOR against the fields its row states (docs/wire.md, "what is sent")."""
    if cond is Condition.TOO_CLOSE:      # min_distance + 1, covariance unknown, never quality 1
        return m.current_distance == m.min_distance + 1 and m.covariance == UINT8_UNKNOWN and m.signal_quality != 1
    return (m.min_distance < m.current_distance <= m.max_distance and 2 <= m.signal_quality <= 100
            and 1 <= m.covariance < UINT8_UNKNOWN)


# -- what arrived ------------------------------------------------------------------------------------

def age_ms(t_arrival: float, m) -> float:
    """Capture to arrival of a DISTANCE_SENSOR, ms (time_boot_ms is CLOCK_MONOTONIC ms modulo 2^32)."""
    return (int(t_arrival * 1000) - m.time_boot_ms) % BOOT_MS_MOD


def captured_at(t_arrival: float, m) -> float:
    """A DISTANCE_SENSOR's capture time on this process's monotonic clock."""
    return t_arrival - age_ms(t_arrival, m) / 1000.0


@dataclass
class Window:
    """What the peer received while the daemon was in one condition (arrival in [t0, t1]).

    ``stale``: per HEARTBEAT, whether the newest reading before it was older than the age limit
    (a reading's own capture stamp says so): the daemon was then stale, which its row allows.
    """

    t0: float
    t1: float
    readings: list
    states: list[str]
    stale: list[bool]
    texts: list[str]
    text_room: bool = True     # the send clock had time to say a STATUSTEXT in it
    notes: list[str] = field(default_factory=list)     # what else the scenario saw
    problems: list[str] = field(default_factory=list)  # what else broke the row (exit code, a traceback)


def window(rx: Receiver, t0: float, t1: float, open_start: bool = False, max_age_ms: float = MAX_AGE_MS) -> Window:
    """Messages that arrived in [t0, t1] (``open_start``: after t0)."""
    msgs = list(rx.msgs)
    got = [(t, m) for t, m in msgs if (t > t0 if open_start else t >= t0) and t <= t1]
    beats = [(t, m) for t, m in got if m.get_type() == "HEARTBEAT"]
    stale = []
    for t, _ in beats:
        newest = [(ta, m) for ta, m in msgs if ta <= t and m.get_type() == "DISTANCE_SENSOR"][-1:]
        stale.append(bool(newest) and age_ms(t, newest[0][1]) > max_age_ms)
    # the clock says at most one STATUSTEXT a second, looking at least every 100 ms
    said = [t for t, m in msgs if m.get_type() == "STATUSTEXT" and t < t0]
    free = max(t0, said[-1] + STATUSTEXT_MIN_S if said else t0)
    return Window(t0, t1, [m for _, m in got if m.get_type() == "DISTANCE_SENSOR"],
                  [STATE_NAME.get(m.system_status, str(m.system_status)) for _, m in beats], stale,
                  [m.text for _, m in got if m.get_type() == "STATUSTEXT"], t1 - free >= CLOCK_LOOK_S)


@dataclass(frozen=True)
class Row:
    name: str
    expected: str
    observed: str
    ok: bool


def judge(cond: Condition, w: Window) -> Row:
    """The row of ``cond`` against what arrived in its window.

    Every HEARTBEAT in it carries the row's state, except a CRITICAL one while the daemon was stale (a
    condition of its own, which a loaded machine may reach between frames): in a condition that sends,
    the newest reading was past its age then; in any, the daemon said "blind (stale)" in the window.
    A window of a HEARTBEAT period or longer holds at least one. The row's STATUSTEXT is in it unless the
    send clock had no room for one (it says at most one a second).
    """
    exp = expected(cond)
    fits = sum(reading_fits(cond, m) for m in w.readings)
    distance_ok = (fits == len(w.readings) > 0) if exp.sends else not w.readings
    said_stale = Condition.STALE.statustext[0] in w.texts
    excused = [st == "critical" != exp.heartbeat and (said_stale or cond.sends and stale)
               for st, stale in zip(w.states, w.stale)]
    own = [st for st, x in zip(w.states, excused) if not x]
    beats_ok = set(own) <= {exp.heartbeat} and (own or w.t1 - w.t0 < HEARTBEAT_PERIOD_S)
    told = [t for t in exp.texts if t in w.texts]
    texts_ok = len(told) == len(exp.texts) or not w.text_room
    ok = distance_ok and bool(beats_ok) and texts_ok and not w.problems
    seen = f"{len(w.readings)} DISTANCE_SENSOR" + (f" ({fits} as the row states)" if w.readings else "")
    beats = ", ".join(f"{own.count(s)} {s}" for s in sorted(set(own))) or "none"
    beats += f" (+{sum(excused)} critical while stale)" if any(excused) else ""
    said = ", ".join(f'"{t}"' for t in dict.fromkeys(w.texts)) or "no STATUSTEXT"
    said += "" if w.text_room else " (no room for one: the last came under a second before)"
    observed = "; ".join([seen, f"HEARTBEAT {beats}", said, *w.notes, *w.problems])
    return Row(f"wire: {cond.value}", str(exp), observed, ok)


def arrival(rx: Receiver, daemon: Daemon, text: str, since: float = 0.0) -> float:
    """When the STATUSTEXT ``text`` first arrived after ``since`` (waiting for it)."""
    def seen():
        return next((t for t, m in rx.timed("STATUSTEXT", since) if m.text == text), None)
    return daemon.wait_for(seen, f'STATUSTEXT "{text}"')


def beats_after(rx: Receiver, daemon: Daemon, since: float, n: int) -> float:
    """The arrival of the ``n``-th HEARTBEAT after ``since``."""
    return daemon.wait_for(lambda: len(rx.timed("HEARTBEAT", since)) >= n and rx.timed("HEARTBEAT", since)[n - 1][0],
                           f"{n} HEARTBEAT")


def stopped(rx: Receiver, daemon: Daemon, sig: int = signal.SIGTERM) -> tuple[float, float, int]:
    """Stop the daemon (or let it stop); (when the peer first heard it shutting down, its last message, exit code).

    Shutting down is heard from the first message that says so: the send clock's STATUSTEXT or a HEARTBEAT
    it sends after the stop began, or the last words ("stopping", then the POWEROFF HEARTBEAT).
    """
    code = daemon.stop(sig)
    exp = expected(Condition.SHUTTING_DOWN)
    # the last words were written before the exit: let the peer's thread read them
    rx.wait(lambda: any(STATE_NAME.get(m.system_status) == exp.heartbeat for m in rx.of("HEARTBEAT")), 10)
    said = {*exp.texts, Condition.SHUTTING_DOWN.statustext[0]}
    began = [t for t, m in list(rx.msgs)
             if (m.get_type() == "STATUSTEXT" and m.text in said)
             or (m.get_type() == "HEARTBEAT" and STATE_NAME.get(m.system_status) == exp.heartbeat)]
    t_began = min(began, default=float("inf"))
    return t_began, max((t for t, _ in rx.msgs), default=t_began), code


def problems_of(daemon: Daemon, code: int | None, want: int = 0) -> list[str]:
    err = daemon.stderr()
    out = [f"exit {code}, not {want}"] if code is not None and code != want else []
    return out + (["a traceback in the log"] if "Traceback" in err else [])
