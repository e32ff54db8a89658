"""The unit's sandbox fits the real daemon.

There is no systemd to start the unit under here, so the test does what its filters do:
it runs the real ``uav-depth run`` (synthetic source, MAVLink to a real pymavlink endpoint,
frame logging and the parameter watcher on) under strace, with every system call that the
unit's SystemCallFilter denies answered EPERM (SystemCallErrorNumber=EPERM), and checks
that the daemon still measures, and that what it did fits MemoryDenyWriteExecute,
RestrictAddressFamilies, ProcSubset=pid and ProtectSystem=strict. The filter sets are
read from deploy/uav-depth.service and expanded by systemd-analyze itself, so editing the
unit re-runs the check against the new sandbox. Needs strace and systemd (.ci/system-deps).
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from functools import lru_cache
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "uav-depth.service"

#: System calls outside the unit's filter that the daemon makes and survives getting EPERM for.
#: mbind: OpenBLAS asks for a NUMA memory policy on its buffers, a hint whose failure it ignores.
#: setpriority: the rig check, the OBSTACLE_DISTANCE pass and the parameter trial's child nice themselves (a
#: hint; on EPERM they run at the daemon's priority: daemon/worker.py and daemon/trial.py catch it).
TOLERATED_DENIED = {"mbind", "setpriority"}
#: /proc files outside the process's own that ProcSubset=pid hides (ENOENT), and why that is fine.
TOLERATED_PROC = {
    "/proc/sys/crypto/fips_enabled": "OpenSSL (imported by Python's hashlib) treats a missing file as non-FIPS",
    "/proc/meminfo": "OpenBLAS / glibc size caches from it and fall back when it is missing",
    "/proc/cpuinfo": "CPU feature probes fall back to cpuid / getauxval",
    "/proc/stat": "os.cpu_count fallbacks; sched_getaffinity answers first",
}


def unit_settings() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key, []).append(value)
    return out


@lru_cache(maxsize=None)
def syscall_groups() -> dict[str, set[str]]:
    text = subprocess.run(["systemd-analyze", "syscall-filter"], capture_output=True, text=True, check=True).stdout
    groups: dict[str, set[str]] = {}
    current = None
    for line in text.splitlines():
        if line.startswith("@"):
            current = line.strip()
            groups[current] = set()
        elif current and line.strip() and not line.strip().startswith("#"):
            groups[current].add(line.strip())
    return groups


def expand(names: list[str]) -> set[str]:
    out: set[str] = set()
    for name in names:
        out |= expand(sorted(syscall_groups()[name])) if name.startswith("@") else {name}
    return out


def allowed_syscalls() -> set[str]:
    """The unit's SystemCallFilter= lines, evaluated as systemd does (allow list, then ~ removals)."""
    allowed: set[str] | None = None
    for value in unit_settings()["SystemCallFilter"]:
        deny = value.startswith("~")
        names = value.lstrip("~").split()
        if deny:
            assert allowed is not None, "the unit must start with an allow list"
            allowed -= expand(names)
        else:
            allowed = (allowed or set()) | expand(names)
    assert allowed
    return allowed


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_daemon_runs_inside_the_units_sandbox(tmp_path):
    from uav_depth.daemon.link.vocabulary import mavutil

    settings = unit_settings()
    assert settings["SystemCallErrorNumber"] == ["EPERM"], "the test emulates EPERM answers"
    allowed = allowed_syscalls()
    port = free_udp_port()
    params = tmp_path / "state" / "params.yaml"
    params.parent.mkdir()
    params.write_text("sgbm:\n  num_disparities: 64\n")    # a missing file flies the defaults blind
    config = {
        "source": {"kind": "synthetic", "fps": 10,
                   "scene": {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 1.0, "seed": 2}},
        "params_file": str(params),
        "mavlink": {"url": f"udpout:127.0.0.1:{port}", "rate_hz": 10, "component_id": 191},
        "logging": {"dir": str(tmp_path / "state" / "logs"), "every_n": 2},
    }
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump(config))
    env = dict(os.environ)
    for assignment in " ".join(settings.get("Environment", [])).split():
        key, value = assignment.split("=", 1)
        env[key] = value
    # sd_notify as systemd gives it: a unix datagram socket and the unit's watchdog period.
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.05)
    env["NOTIFY_SOCKET"] = str(tmp_path / "notify")
    env["WATCHDOG_USEC"] = str(int(float(settings["WatchdogSec"][0]) * 1e6))
    trace = tmp_path / "trace"
    inject = "!" + ",".join("?" + s for s in sorted(allowed))
    cmd = ["strace", "-f", "-qq", "-o", str(trace), "-e", "trace=all", "-e", f"inject={inject}:error=EPERM",
           sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(cfg)]
    listener = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=250)
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    valid = 0
    try:
        deadline = time.monotonic() + 120
        while valid < 10 and time.monotonic() < deadline and proc.poll() is None:
            msg = listener.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=1.0)
            if msg is not None and msg.signal_quality > 1 and msg.min_distance <= msg.current_distance <= msg.max_distance:
                valid += 1
        # exercise the hot reload path too, then stop as systemd does
        params.write_text("sgbm:\n  block_size: 7\n")
        time.sleep(2.0)
        notes = []
        while True:
            try:
                notes.append(notify.recv(4096).decode())
            except OSError:
                break
    finally:
        # strace blocks SIGTERM for itself: stop the daemon under it, as systemd would.
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
        pids = [int(p) for p in children.read_text().split()] if children.exists() else []
        for pid in pids:
            os.kill(pid, signal.SIGTERM)
        if not pids:
            proc.terminate()
        out, _ = proc.communicate(timeout=60)
        listener.close()
        notify.close()
    assert valid >= 10, f"the daemon did not measure inside the sandbox:\n{out[-3000:]}"
    assert proc.returncode == 0, out[-3000:]
    assert any("READY=1" in n for n in notes) and any("WATCHDOG=1" in n for n in notes), notes

    text = trace.read_text(errors="replace")
    calls = re.findall(r"^\d+\s+([a-z_0-9]+)\(", text, re.M)
    denied_used = {name for name in calls if name not in allowed}
    assert denied_used <= TOLERATED_DENIED, (
        f"system calls outside SystemCallFilter: {sorted(denied_used - TOLERATED_DENIED)}")
    # MemoryDenyWriteExecute=yes: no writable+executable mapping, no mapping made executable later.
    wx = [line for line in text.splitlines()
          if re.search(r"\bmmap\(.*PROT_WRITE.*PROT_EXEC|\bmmap\(.*PROT_EXEC.*PROT_WRITE", line)
          or re.search(r"\b(pkey_)?mprotect\(.*PROT_EXEC", line)]
    assert not wx, "W^X violations:\n" + "\n".join(wx[:5])
    families = set(re.findall(r"\bsocket\((AF_[A-Z0-9]+)", text))
    assert families <= set(settings["RestrictAddressFamilies"][0].split()), families
    # ProcSubset=pid: only the process's own /proc entries exist.
    proc_paths = set(re.findall(r'open(?:at)?\([^"]*"(/proc/[^"]*)"', text))
    foreign = {p for p in proc_paths if not re.match(r"^/proc/(self|thread-self|\d+)(/|$)", p)}
    assert foreign <= set(TOLERATED_PROC), f"/proc files hidden by ProcSubset=pid: {sorted(foreign)}"
    # ProtectSystem=strict: writes only to the state directory (ReadWritePaths), /tmp (PrivateTmp: the parameter
    # trial's child writes its stderr to an unnamed O_TMPFILE there) and /dev.
    writes = set(re.findall(r'open(?:at)?\([^"]*"([^"]+)", [^)]*O_(?:WRONLY|RDWR|CREAT)', text))
    outside = {p for p in writes if p != "/tmp" and not p.startswith((str(tmp_path), "/tmp/", "/dev/"))}
    assert not outside, f"writes outside ReadWritePaths: {sorted(outside)}"
