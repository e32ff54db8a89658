"""Signals against the real daemon process: right after exec, and under the unit's own start.

Each fault ends in one line and the documented exit code (78 for anything in a
config, parameter or key file), or, while flying, in one log line with the last
good parameters kept: never a traceback, a restart loop or a silent change.
See docs/operations.md.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from mavlink_peer import Receiver
from daemon_process import GOOD, config, run_daemon


# -- signals right after exec ------------------------------------------------------------------------

def _caught(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return int(line.split()[1], 16)
    return 0


def _blocked(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigBlk:"):
            return int(line.split()[1], 16)
    return 0


WANTED = sum(1 << (s - 1) for s in (signal.SIGHUP, signal.SIGINT, signal.SIGUSR1, signal.SIGTERM))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
def test_a_signal_right_after_exec_is_handled_before_any_slow_import(tmp_path, sig):
    rx = Receiver()
    (tmp_path / "params.yaml").write_bytes(GOOD)
    daemon = run_daemon(tmp_path, config(rx.port, tmp_path / "params.yaml"))
    try:
        pid = daemon.proc.pid
        deadline = time.monotonic() + 60
        while _caught(pid) & WANTED != WANTED:
            assert time.monotonic() < deadline and daemon.proc.poll() is None, daemon.stderr()
            time.sleep(0.001)
        maps = Path(f"/proc/{pid}/maps").read_text()
        daemon.proc.send_signal(sig)
        # The handlers were in before NumPy, OpenCV or pymavlink were loaded.
        assert "numpy" not in maps and "cv2" not in maps, "handlers installed after the slow imports"
        if sig == signal.SIGHUP:
            assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR")) >= 5, timeout=180), daemon.stderr()[-3000:]
            daemon.proc.send_signal(signal.SIGTERM)
        code = daemon.wait(60)
    finally:
        daemon.kill()
        rx.close()
    err = daemon.stderr()
    assert code == 0, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and "interrupted" not in err
    assert "signal handlers installed" in err and " ms after exec" in err
    if sig == signal.SIGHUP:
        assert "SIGHUP before start-up: nothing to reload yet" in err
    else:
        assert f"stopped before start-up finished ({sig.name})" in err or "shutdown complete" in err


def unit_exec_prefix() -> list[str]:
    """What deploy/uav-depth.service puts before the daemon's command (``env --block-signal=...``)."""
    unit = Path(__file__).resolve().parents[2] / "deploy" / "uav-depth.service"
    line = next(ln for ln in unit.read_text().splitlines() if ln.startswith("ExecStart="))
    words = line.split("=", 1)[1].split()
    return words[:next(i for i, w in enumerate(words) if w.endswith("/bin/uav-depth"))]


def test_the_unit_holds_exactly_the_signals_the_daemon_handles():
    from uav_depth.cli.signals import HANDLED

    prefix = unit_exec_prefix()
    assert prefix[0] == "/usr/bin/env" and prefix[1].startswith("--block-signal=")
    assert sorted(prefix[1].split("=", 1)[1].split(",")) == sorted(s.name[3:] for s in HANDLED)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
def test_a_signal_sent_at_exec_under_the_units_start_is_handled_with_one_line(tmp_path, sig):
    # Sent before the interpreter has run a line: only the unit's blocked start can keep it for the handlers.
    rx = Receiver()
    (tmp_path / "params.yaml").write_bytes(GOOD)
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config(rx.port, tmp_path / "params.yaml")))
    err_path = tmp_path / "stderr.txt"
    proc = subprocess.Popen([*unit_exec_prefix(), sys.executable, "-m", "uav_depth.cli.main", "run", "--config",
                             str(path)], stdout=subprocess.DEVNULL, stderr=open(err_path, "w"))
    try:
        deadline = time.monotonic() + 60
        while _blocked(proc.pid) & WANTED != WANTED:     # env has blocked them (microseconds after exec)
            assert time.monotonic() < deadline and proc.poll() is None, err_path.read_text()
        proc.send_signal(sig)
        if sig == signal.SIGHUP:
            assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR")) >= 3, timeout=180), err_path.read_text()[-3000:]
            proc.send_signal(signal.SIGTERM)
        code = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        rx.close()
    err = err_path.read_text()
    assert code == 0, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert f"({sig.name} sent before then: held blocked, handled now)" in err, err[-3000:]
    if sig == signal.SIGHUP:
        assert "SIGHUP before start-up: nothing to reload yet" in err
    else:
        assert f"stopped before start-up finished ({sig.name})" in err, err[-3000:]
