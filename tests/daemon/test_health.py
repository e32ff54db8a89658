"""Every thread's death is a health failure: WATCHDOG=1 stops, so systemd restarts the daemon.

A thread is killed the way an unforeseen error would end it: an exception raised inside it
(``PyThreadState_SetAsyncExc``) that its own handlers do not catch. In-process for every thread
the service runs; on the real ``uav-depth run`` process (a SIGUSR2 handler of the test's
wrapper does the killing) with systemd's notify socket standing in.
"""

import ctypes
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
import yaml

from uav_depth.cli.sources import SOURCES
from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.daemon.config import run_config_from_dict
from uav_depth.daemon.service import Service

from mavlink_peer import free_port
from notify_socket import NotifySocket


SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 0.8, "seed": 1}
PARAMS_64 = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
PATIENCE_S = 120


class ThreadKilled(BaseException):
    """Not an Exception: no ``except Exception`` of the daemon's loops catches it."""


def kill_thread(name: str) -> None:
    hits = [t for t in threading.enumerate() if t.name == name]
    assert len(hits) == 1, [t.name for t in threading.enumerate()]
    assert ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(hits[0].ident), ctypes.py_object(ThreadKilled))


def every_part_config(rx, tmp_path):
    path = tmp_path / "params.yaml"
    save_params(PARAMS_64, path)
    return run_config_from_dict({
        "source": {"kind": "synthetic", "fps": 10, "scene": SCENE}, "params_file": str(path),
        "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 20}, "ranging": {"max_age_ms": 499},
        "logging": {"dir": str(tmp_path / "logs"), "every_n": 5},
        "liveview": {"enabled": True, "port": free_port(socket.SOCK_STREAM)}, "rig_check": {"interval_s": 1.0},
        "obstacle_distance": {"enabled": True},
        "service": {"frame_timeout_s": 10.0, "params_poll_s": 0.1, "status_interval_s": 0.5}}, sources=SOURCES)


#: Every thread a service with every part on runs (stereo and capture last: the others need frames).
THREADS = ("params-watch", "frame-logger", "liveview", "rig-check", "obstacles", "mavlink-clock", "mavlink-io",
           "capture", "stereo")


def test_every_threads_death_stops_the_watchdog_and_is_said(rx, tmp_path, caplog):
    svc = Service(every_part_config(rx, tmp_path))
    stop = threading.Event()
    runner = threading.Thread(target=svc.run, args=(stop,), daemon=True)
    runner.start()
    try:
        assert rx.wait(lambda: svc.stats.frames >= 3, PATIENCE_S), "never measured"
        assert set(svc.health.watched) == set(THREADS)
        assert svc.healthy()
        dead: tuple[str, ...] = ()
        for name in THREADS:
            kill_thread(name)
            dead += (name,)
            assert rx.wait(lambda: set(svc.health.dead) == set(dead), PATIENCE_S), (name, svc.health.dead)
            assert not svc.healthy()
            assert f"THREAD {name} DEAD" in svc.status_line()
            assert any(f"died: WATCHDOG=1 stops, so systemd restarts the daemon" in r.getMessage()
                       and name in r.getMessage() for r in caplog.records)
    finally:
        stop.set()
        runner.join(60)
    assert not runner.is_alive()


WRAPPER = """
import ctypes, signal, sys, threading

class ThreadKilled(BaseException):
    pass

NAME = sys.argv[1]

def kill(signum, frame):
    for t in threading.enumerate():
        if t.name == NAME:
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(t.ident), ctypes.py_object(ThreadKilled))

signal.signal(signal.SIGUSR2, kill)
sys.argv = ["uav-depth", "run", "--config", sys.argv[2]]
from uav_depth.cli.main import entry
entry()
"""


@pytest.mark.parametrize("thread", ["mavlink-io", "params-watch"])
def test_a_dead_thread_of_the_real_daemon_stops_its_watchdog(rx, tmp_path, thread):
    save_params(PARAMS_64, tmp_path / "params.yaml")
    cfg = {"source": {"kind": "synthetic", "fps": 10, "scene": SCENE}, "params_file": str(tmp_path / "params.yaml"),
           "mavlink": {"url": f"udpout:127.0.0.1:{rx.port}", "rate_hz": 20}, "ranging": {"max_age_ms": 499},
           "service": {"frame_timeout_s": 10.0, "status_interval_s": 0.5}}
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(cfg))
    notify = NotifySocket(tmp_path / "notify")
    err = tmp_path / "stderr"
    proc = subprocess.Popen([sys.executable, "-c", WRAPPER, thread, str(tmp_path / "run.yaml")],
                            stdout=subprocess.DEVNULL, stderr=open(err, "w"),
                            env={**os.environ, "NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "600000"})
    try:
        assert rx.wait(lambda: "READY=1" in notify.lines() and "WATCHDOG=1" in notify.lines(), PATIENCE_S), \
            err.read_text()[-3000:]
        t_kill = time.monotonic()
        proc.send_signal(signal.SIGUSR2)
        # The watchdog is fed every 0.2 s while healthy; after the death it is never fed again.
        assert rx.wait(lambda: f"thread {thread} died" in err.read_text(), PATIENCE_S), err.read_text()[-3000:]
        t_seen = time.monotonic()
        assert rx.wait(lambda: time.monotonic() - t_seen > 3.0, 10)
        assert proc.poll() is None, "the daemon must not stop itself: systemd restarts it"
        dogs = [t for t, d in notify.datagrams if "WATCHDOG=1" in d.split("\n")]
        assert dogs and max(dogs) < t_seen + 0.5, (max(dogs) - t_kill, t_seen - t_kill)
        assert f"THREAD {thread} DEAD" in [d for _, d in notify.datagrams if d.startswith("STATUS=")][-1]
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
        notify.close()
