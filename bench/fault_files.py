"""bench/faults.py's rows for what the daemon reads: files at start-up and on SIGHUP, the link's url, --set.

Each case starts the real ``uav-depth`` process; the bad files are those of the fault tests
(tests/daemon/test_faults.py), reused here so that both judge the same bytes.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from mavlink_peer import Receiver, free_port
from daemon_process import OVERSIZE_PARAMS, THREE_WAY_100, alias_bomb
from wire_rows import GOOD, PARAMS_64, Daemon, Row, age_ms, config

from uav_depth.cli.exit_codes import EXIT_CONFIG, EXIT_UNAVAILABLE
from uav_depth.core.params import DEFAULT_PARAMS, dump_params

#: The schema allows uniqueness 100 with the default mode; it is run in the trial child before it flies.
UNIQUE_100 = dump_params(PARAMS_64).replace("uniqueness_ratio: 10\n", "uniqueness_ratio: 100\n").encode()
UNIQUE_100_HASH = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64, "sgbm.uniqueness_ratio": 100}).hash()
FIFO = b"<a FIFO>"
#: A stream gap the reload may add: ArduPilot drops a sensor after 500 ms without a message.
GAP_LIMIT_MS = 500.0


def _error_lines(err: str, command: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith(f"uav-depth {command}: error: ")]


def _write_params(path: Path, data: bytes) -> None:
    if path.exists() or path.is_symlink():
        path.unlink()
    if data is FIFO:
        os.mkfifo(path)
    else:
        path.write_bytes(data)


def refused_at_start(name: str, want: int, message: str, params: bytes | None = None, checks: tuple = ("", "--check"),
                     **sections) -> "callable":
    """A case: ``run`` and ``run --check`` each exit ``want`` with one line matching ``message``, no traceback."""
    def case(d: Path) -> list[Row]:
        params_file = d / "params.yaml"
        _write_params(params_file, GOOD.encode() if params is None else params)
        cfg = config(free_port(), params_file, **sections)
        seen, ok = [], True
        for extra in checks:
            t0 = time.monotonic()
            daemon = Daemon(d, cfg, *([extra] if extra else []))
            code = daemon.exit_code(180)
            command = f"run {extra}".strip()
            lines, err = _error_lines(daemon.stderr(), command), daemon.stderr()
            good = code == want and len(lines) == 1 and re.search(message, lines[0]) and "Traceback" not in err
            ok &= bool(good)
            said = lines[0].split(": error: ", 1)[1] if lines else (err.strip().splitlines() or ["-"])[-1]
            said = said.replace(f"{d}/", "")[:90]
            seen.append(f"{command}: exit {code} after {time.monotonic() - t0:.1f} s, {len(lines)} line(s): {said}")
        return [Row(name, f"exit {want}, one line /{message}/, no traceback", "; ".join(seen), ok)]
    case.__doc__ = name
    return case


def port_in_use(d: Path) -> list[Row]:
    """``run --check`` toward a udpin port another program holds."""
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    try:
        url = f"udpin:127.0.0.1:{holder.getsockname()[1]}"
        return refused_at_start("udpin port held by another program: run --check", EXIT_UNAVAILABLE,
                                r"mavlink\.url .*", checks=("--check",), mavlink={"url": url})(d)
    finally:
        holder.close()


def bad_set_key(d: Path) -> list[Row]:
    """``--set nosuch.key=1`` on evaluate and tune: exit 78 and one line (a KeyError traceback before)."""
    (d / "log").mkdir()
    seen, ok = [], True
    for command in ("evaluate", "tune"):
        proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", command, "--set", "nosuch.key=1",
                               str(d / "log")], capture_output=True, text=True, timeout=180)
        lines = _error_lines(proc.stderr, command)
        ok &= proc.returncode == EXIT_CONFIG and len(lines) == 1 and "Traceback" not in proc.stderr
        said = f": {lines[0][:70]}" if lines else ""
        seen.append(f"{command}: exit {proc.returncode}, {len(lines)} line(s){said}")
    return [Row("--set nosuch.key=1 (evaluate, tune)", f"exit {EXIT_CONFIG}, one line, no traceback", "; ".join(seen),
                ok)]


def params_check(d: Path) -> list[Row]:
    """``params check`` on the uniqueness-100 files: the 3-way one refused, the default-mode one run in a child."""
    seen, ok = [], True
    for name, data, want in (("3-way", THREE_WAY_100, EXIT_CONFIG), ("sgbm", UNIQUE_100, 0)):
        path = d / f"unique-100-{name}.yaml"
        path.write_bytes(data)
        proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "params", "check", str(path)],
                              capture_output=True, text=True, timeout=180)
        ok &= proc.returncode == want and "Traceback" not in proc.stderr
        seen.append(f"{name}: exit {proc.returncode}")
    return [Row("uniqueness 100: params check", f"3-way: exit {EXIT_CONFIG} (OpenCV divides by 100 - u); "
                "sgbm: exit 0 (test render in a child)", "; ".join(seen), ok)]


START_UP = [
    refused_at_start("uniqueness 100 (3-way) parameter file at start", EXIT_CONFIG,
                     r"uniqueness_ratio must be at most 99 with sgbm\.mode sgbm_3way", THREE_WAY_100),
    refused_at_start("alias-bomb parameter file at start", EXIT_CONFIG, r"uses a YAML anchor", alias_bomb()),
    refused_at_start("oversize parameter file at start", EXIT_CONFIG, r"more than the 64 KiB", OVERSIZE_PARAMS),
    refused_at_start("FIFO as the parameter file at start", EXIT_CONFIG, r"not a regular file", FIFO),
    refused_at_start("synthetic scene 100000 x 100000 px", EXIT_CONFIG, r"source\.scene\.width must be between",
                     source={"kind": "synthetic", "scene": {"width": 100000, "height": 100000}}),
    refused_at_start("unreachable serial link: run --check", EXIT_UNAVAILABLE, r"/dev/ttyNOSUCH0 does not exist",
                     checks=("--check",), mavlink={"url": "/dev/ttyNOSUCH0"}),
    port_in_use,
    bad_set_key,
    params_check,
]


# -- on SIGHUP: refused (or run) while the stream goes on -----------------------------------------------

RELOADS = [
    ("uniqueness 100 (3-way) parameter file on SIGHUP", THREE_WAY_100, False),
    ("alias-bomb parameter file on SIGHUP", alias_bomb(), False),
    ("oversize parameter file on SIGHUP", OVERSIZE_PARAMS, False),
    ("FIFO as the parameter file on SIGHUP", FIFO, False),
    ("uniqueness 100 (sgbm) parameter file on SIGHUP", UNIQUE_100, True),
]


def _max_gap_ms(rx: Receiver, t0: float, t1: float) -> float:
    """The largest gap between consecutive readings' capture stamps among those that arrived in [t0, t1]."""
    stamps = [t - age_ms(t, m) / 1000.0 for t, m in rx.timed("DISTANCE_SENSOR", t0) if t <= t1]
    return max((b - a for a, b in zip(stamps, stamps[1:])), default=float("inf")) * 1000.0


def _one_reload(rx: Receiver, daemon: Daemon, path: Path, name: str, data: bytes, loads: bool) -> Row:
    kept = f"uav-depth: params rejected, kept {PARAMS_64.hash()[:8]}"
    said = f"uav-depth: params {UNIQUE_100_HASH[:8]} loaded" if loads else kept
    t_before = rx.timed("DISTANCE_SENSOR")[-10][0]
    tmp = path.with_name("new.yaml")
    _write_params(tmp, data)
    t0 = time.monotonic()
    os.replace(tmp, path)
    daemon.proc.send_signal(signal.SIGHUP)
    t_said = daemon.wait_for(lambda: next((t for t, m in rx.timed("STATUSTEXT", t0) if m.text == said), None),
                             f'STATUSTEXT "{said}"')
    heard = f'"{said}" {1000 * (t_said - t0):.0f} ms after SIGHUP'
    if loads:    # uniqueness 100 keeps almost no match: it flies, and says what it measures (or that it is blind)
        daemon.wait_for(lambda: len(rx.of("HEARTBEAT", t_said)) >= 3, "3 HEARTBEAT after it")
        texts = ", ".join(f'"{m.text}"' for m in rx.of("STATUSTEXT", t_said))
        ok = daemon.proc.poll() is None and "Traceback" not in daemon.stderr()
        return Row(name, "run in the trial child, then flies: the daemon lives, HEARTBEAT goes on",
                   f"{heard}; then {len(rx.of('DISTANCE_SENSOR', t_said))} DISTANCE_SENSOR, {texts or 'no STATUSTEXT'}"
                   f"; alive: {daemon.proc.poll() is None}", ok)
    daemon.wait_for(lambda: len(rx.of("DISTANCE_SENSOR", t_said)) >= 10, "10 readings after it")
    t1 = rx.timed("DISTANCE_SENSOR", t_said)[9][0]
    before, during = _max_gap_ms(rx, t_before, t0), _max_gap_ms(rx, t0, t1)
    ok = daemon.proc.poll() is None and "Traceback" not in daemon.stderr() and during <= max(GAP_LIMIT_MS, before)
    return Row(name, f"refused, last good kept, daemon flies, no gap over {GAP_LIMIT_MS:.0f} ms (or the gap before)",
               f"{heard}; largest gap {during:.0f} ms (before: {before:.0f} ms); alive: {daemon.proc.poll() is None}",
               ok)


def reloads(d: Path) -> list[Row]:
    """One flying daemon; each file of RELOADS replaces its parameter file, then SIGHUP."""
    rx = Receiver()
    path = d / "params.yaml"
    path.write_text(GOOD)
    daemon = Daemon(d, config(rx.port, path))
    rows = []
    try:
        daemon.wait_for(lambda: len(rx.of("DISTANCE_SENSOR")) >= 10, "10 readings")
        for name, data, loads in RELOADS:
            try:
                rows.append(_one_reload(rx, daemon, path, name, data, loads))
            except AssertionError as exc:
                rows.append(Row(name, "refused or loaded, daemon flies", str(exc).splitlines()[0][:200], False))
    finally:
        daemon.stop()
        daemon.kill()
        rx.close()
    return rows
