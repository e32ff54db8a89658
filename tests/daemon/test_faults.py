"""Faults against the real daemon process (`uav-depth run`, synthetic source, a pymavlink peer on loopback).

Each fault ends in one line and the documented exit code (78 for anything in a
config, parameter or key file), or, while flying, in one log line with the last
good parameters kept: never a traceback, a restart loop or a silent change.
See docs/operations.md.
"""

from __future__ import annotations

import functools
import os
import pwd
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from uav_depth.cli.exit_codes import EXIT_CONFIG, EXIT_UNAVAILABLE
from uav_depth.core.params import DEFAULT_PARAMS, dump_params
from uav_depth.core.session import SessionWriter
from uav_depth.sim.scene import Scene, SceneConfig

from mavlink_peer import Receiver

SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 0.8, "branch_radius_m": 0.04,
         "seed": 1}
PARAMS_64 = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
GOOD = dump_params(PARAMS_64).encode()
IS_ROOT = os.geteuid() == 0
KEY_HEX = b"00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff\n"


def config(port: int, params_file: Path | str | None, **extra) -> dict:
    cfg = {"source": {"kind": "synthetic", "fps": 10, "scene": SCENE},
           "params_file": str(params_file) if params_file else None,
           "ranging": {"max_age_ms": 450},
           "mavlink": {"url": f"udpout:127.0.0.1:{port}", "rate_hz": 20},
           "service": {"shutdown_timeout_s": 3.0, "status_interval_s": 1.0, "params_poll_s": 0.2,
                       "first_frame_timeout_s": 120.0}}
    for key, value in extra.items():
        if key != "source" and isinstance(value, dict) and isinstance(cfg.get(key), dict):
            cfg[key] = {**cfg[key], **value}
        else:
            cfg[key] = value
    return cfg


def as_nobody() -> list[str]:
    """Prefix that runs a command as an unprivileged user (root reads every file, whatever its mode).

    Needs setpriv (util-linux): missing, the test skips with that reason on a laptop and fails in CI
    (``CI=true``). Where ``nobody`` cannot run this interpreter or import uav_depth (a virtualenv under
    a private home), every daemon would die of that before reading its files: the test skips and says so.
    """
    if not IS_ROOT:
        return []
    return _nobody_prefix()


@functools.lru_cache(maxsize=None)
def _nobody_check() -> tuple[list[str], str | None]:
    if shutil.which("setpriv") is None:
        return [], "setpriv (util-linux) is not installed"
    pw = pwd.getpwnam("nobody")
    prefix = ["setpriv", f"--reuid={pw.pw_uid}", f"--regid={pw.pw_gid}", "--clear-groups"]
    # The daemon also starts this interpreter again (the parameter trial's child process).
    probe = subprocess.run([*prefix, sys.executable, "-c", "import subprocess, sys, uav_depth.cli.main; "
                            "subprocess.run([sys.executable, '-c', 'import uav_depth.daemon.trial'], check=True)"],
                           capture_output=True, text=True, timeout=120, cwd="/")
    if probe.returncode != 0:
        last = (probe.stderr.strip().splitlines() or [f"exit {probe.returncode}"])[-1]
        return [], f"the user nobody cannot run {sys.executable} with uav_depth ({last})"
    return prefix, None


def _nobody_prefix() -> list[str]:
    prefix, problem = _nobody_check()
    if problem is None:
        return prefix
    if problem.startswith("setpriv") and os.environ.get("CI") == "true":
        pytest.fail(f"{problem}: CI must have it (.ci/system-deps)")
    pytest.skip(problem)


class Daemon:
    """``uav-depth run`` (or any subcommand) as a real process, stderr captured to a file."""

    def __init__(self, workdir: Path, args: list[str], *, cwd: Path | None = None, user: list[str] | None = None):
        self.stderr_path = workdir / f"stderr-{time.monotonic_ns()}.txt"
        self._err = open(self.stderr_path, "w")
        os.chmod(self.stderr_path, 0o666)
        self.proc = subprocess.Popen([*(user or []), sys.executable, "-m", "uav_depth.cli.main", *args],
                                     stdout=subprocess.PIPE, stderr=self._err, cwd=cwd,
                                     env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})

    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"still running after {timeout} s:\n{self.stderr()[-3000:]}")

    def wait_for(self, pred, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pred():
                return
            if self.proc.poll() is not None:
                raise AssertionError(f"exited with {self.proc.returncode} while waiting for {what}:\n"
                                     f"{self.stderr()[-3000:]}")
            time.sleep(0.02)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}:\n{self.stderr()[-3000:]}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self._err.close()


def run_daemon(workdir: Path, cfg: dict | bytes, *extra: str, user: list[str] | None = None,
               cwd: Path | None = None, name: str = "run.yaml") -> Daemon:
    path = workdir / name
    path.write_bytes(cfg if isinstance(cfg, bytes) else yaml.safe_dump(cfg).encode())
    os.chmod(path, 0o644)
    return Daemon(workdir, ["run", "--config", str(path), *extra], cwd=cwd, user=user)


def one_error_line(err: str, command: str = "run") -> str:
    """The single ``uav-depth <command>: error:`` line (and no traceback)."""
    assert "Traceback" not in err, err[-3000:]
    lines = [ln for ln in err.splitlines() if ln.startswith(f"uav-depth {command}: error: ")]
    assert len(lines) == 1, err[-3000:]
    return lines[0]


@pytest.fixture
def shared_dir():
    """A directory every user can enter (pytest's tmp_path is private to root)."""
    d = Path(tempfile.mkdtemp(prefix="uav-depth-faults-", dir="/tmp"))
    os.chmod(d, 0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def port():
    from mavlink_peer import free_port

    return free_port()


# -- start-up: one line, exit 78 ---------------------------------------------------------------------

def _params_with(**changes) -> bytes:
    return dump_params(PARAMS_64.replace(**changes)).encode()


def _setup_params(data: bytes):
    def setup(d: Path, port: int):
        (d / "params.yaml").write_bytes(data)
        return config(port, d / "params.yaml")
    return setup


def _setup_config_bytes(data: bytes):
    def setup(d: Path, port: int):
        return data
    return setup


def _setup_key_directory(d: Path, port: int):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "keydir").mkdir(mode=0o700)
    return config(port, d / "params.yaml", mavlink={"signing_key_file": str(d / "keydir")})


def _setup_key_unreadable(d: Path, port: int):
    # Root-owned 0600 and the daemon runs as nobody (as root); 0000 when the tests are not root.
    (d / "params.yaml").write_bytes(GOOD)
    key = d / "key.txt"
    key.write_bytes(KEY_HEX)
    os.chmod(key, 0o600 if IS_ROOT else 0o000)
    return config(port, d / "params.yaml", mavlink={"signing_key_file": str(key)})


def _setup_logdir_under_a_file(d: Path, port: int):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "plain-file").write_text("x")
    return config(port, d / "params.yaml", logging={"dir": str(d / "plain-file" / "logs")})


def _setup_logdir_not_writable(d: Path, port: int):
    # Like /var/lib/uav-depth without permission: it exists, the service user may not write in it.
    (d / "params.yaml").write_bytes(GOOD)
    logs = d / "logs"
    logs.mkdir()
    os.chmod(logs, 0o755 if IS_ROOT else 0o555)
    return config(port, d / "params.yaml", logging={"dir": str(logs)})


DUPLICATE_CONFIG = b"""source:
  kind: synthetic
mavlink:
  rate_hz: 20
mavlink:
  rate_hz: 50
"""

def alias_bomb(levels: int = 9) -> bytes:
    """Under 1 KB of YAML that expands into 9**levels strings (the "billion laughs")."""
    lines = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return ("\n".join(lines) + "\n").encode()


OVERSIZE_PARAMS = GOOD + b"# padding\n" * 7000      # a valid file, past the 64 KiB cap

#: OpenCV's 3-way matcher dies of SIGFPE at uniqueness 100 (issue 44: params check passed it, run died).
THREE_WAY_100 = _params_with(**{"sgbm.mode": "sgbm_3way"}).replace(b"uniqueness_ratio: 10\n",
                                                                   b"uniqueness_ratio: 100\n")

STARTUP_FAULTS = [
    pytest.param(_setup_params(THREE_WAY_100), r"sgbm\.uniqueness_ratio must be at most 99 with sgbm\.mode sgbm_3way",
                 id="params-3way-uniqueness-100"),
    pytest.param(_setup_params(alias_bomb()), r"parameter file uses a YAML anchor \('l0'\) at line 1",
                 id="params-alias-bomb"),
    pytest.param(_setup_params(OVERSIZE_PARAMS), r"parameter file is \d+ bytes, more than the 64 KiB",
                 id="params-over-the-size-cap"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic\n  scene: {width: 100000, height: 100000}\n"),
                 r"source\.scene\.width must be between 32 and 4096, but got 100000", id="scene-100000-px"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic\n" + alias_bomb()),
                 r"config uses a YAML anchor \('l0'\) at line 3", id="config-alias-bomb"),
    pytest.param(_setup_params(b"sgbm:\n  p1: 600  # caf\xe9\n"), r"parameter file is not UTF-8 text \(byte 0xe9",
                 id="params-not-utf8"),
    pytest.param(_setup_params(b""), r"must set at least one section \(sgbm, wls, compute\); an empty file is not",
                 id="params-empty"),
    pytest.param(_setup_params(b"# tuned later\n"), r"must set at least one section", id="params-only-comments"),
    pytest.param(_setup_params(b"sgbm:\n  p1: 600\n  p2: 2400\n  p1: 900\n"),
                 r"sgbm\.p1 is given twice \(line 2 and line 4\)", id="params-duplicate-key"),
    pytest.param(_setup_params(_params_with(**{"sgbm.p2": 40000})), r"sgbm\.p2 must be at most 32767",
                 id="params-p2-over-16-bit-costs"),
    pytest.param(_setup_params(_params_with(**{"sgbm.p1": 33000, "sgbm.p2": 34000})), r"sgbm\.p1 must be at most 32767",
                 id="params-p1-over-16-bit-costs"),
    pytest.param(_setup_params(_params_with(**{"sgbm.num_disparities": 320})),
                 r"sgbm\.num_disparities must leave columns to match.*matched image width 320 px",
                 id="params-search-range-wider-than-image"),
    pytest.param(_setup_params(_params_with(**{"sgbm.num_disparities": 224, "sgbm.block_size": 31})),
                 r"\(parameters\) must measure a test render .*they measured nothing",
                 id="params-search-range-hides-the-roi"),
    pytest.param(_setup_config_bytes(b"\x7fELF\x02\x01\x01\x00\x00\x00binary"), r"config is a binary file",
                 id="config-binary"),
    pytest.param(_setup_config_bytes(b"source:\n  kind: synthetic  # \xff\n"), r"config is not UTF-8 text",
                 id="config-not-utf8"),
    pytest.param(_setup_config_bytes(DUPLICATE_CONFIG), r"mavlink is given twice \(line 3 and line 5\)",
                 id="config-duplicate-key"),
    pytest.param(_setup_key_directory, r"mavlink\.signing_key_file must name a file, not a directory",
                 id="key-is-a-directory"),
    pytest.param(_setup_key_unreadable, r"mavlink\.signing_key_file must be readable by this user .*Permission denied",
                 id="key-unreadable-by-the-service-user"),
    pytest.param(_setup_logdir_under_a_file, r"logging\.dir must be a directory this user .* can create and write",
                 id="logdir-cannot-be-created"),
    pytest.param(_setup_logdir_not_writable, r"logging\.dir must be a directory this user .* can create and write",
                 id="logdir-not-writable"),
]


#: The faults only an unprivileged user meets (root reads and writes whatever the modes say).
AS_NOBODY = (_setup_key_unreadable, _setup_logdir_not_writable)


@pytest.mark.parametrize("setup,message", STARTUP_FAULTS)
def test_a_fault_in_a_file_is_one_line_and_exit_78_for_run_and_run_check(shared_dir, port, setup, message):
    user = as_nobody() if setup in AS_NOBODY else None
    cfg = setup(shared_dir, port)
    for extra in ((), ("--check",)):
        daemon = run_daemon(shared_dir, cfg, *extra, user=user)
        try:
            code = daemon.wait(120)
        finally:
            daemon.kill()
        err = daemon.stderr()
        line = one_error_line(err, "run --check" if extra else "run")
        assert code == EXIT_CONFIG, err[-3000:]
        assert re.search(message, line), line


# -- run --check refuses what run refuses -------------------------------------------------------------

def _check_params_p2_below_p1(d, port):
    (d / "params.yaml").write_bytes(b"sgbm:\n  p1: 900\n  p2: 800\n")
    return config(port, d / "params.yaml"), EXIT_CONFIG, r"sgbm\.p2 must be greater than sgbm\.p1 \(900\)"


def _check_params_not_yaml(d, port):
    (d / "params.yaml").write_bytes(b"sgbm: [1, 2\n")
    return config(port, d / "params.yaml"), EXIT_CONFIG, r"parameter file is not valid YAML at line 2"


def _check_key_mode_0644(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    (d / "key.txt").write_bytes(KEY_HEX)
    os.chmod(d / "key.txt", 0o644)
    return (config(port, d / "params.yaml", mavlink={"signing_key_file": str(d / "key.txt")}), EXIT_CONFIG,
            r"signing_key_file must not be accessible by group or others \(chmod 600\)")


def _check_replay_path_missing(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    return (config(port, d / "params.yaml", source={"kind": "replay", "path": str(d / "no-such-log")}),
            EXIT_UNAVAILABLE, r"replay: .*no-such-log")


def _check_zed_calibration_missing(d, port):
    (d / "params.yaml").write_bytes(GOOD)
    return (config(port, d / "params.yaml", source={"kind": "uvc", "device": "/dev/video97",
                                                     "zed_calibration": str(d / "SN000.conf")}),
            EXIT_CONFIG, r"SN000\.conf: ZED calibration file not found")


@pytest.mark.parametrize("setup", [
    pytest.param(_check_params_p2_below_p1, id="params-p2-below-p1"),
    pytest.param(_check_params_not_yaml, id="params-malformed"),
    pytest.param(_check_key_mode_0644, id="key-mode-0644"),
    pytest.param(_check_replay_path_missing, id="replay-path-missing"),
    pytest.param(_check_zed_calibration_missing, id="zed-calibration-missing"),
])
def test_run_check_refuses_what_run_refuses_with_the_same_line_and_code(tmp_path, port, setup):
    cfg, code, message = setup(tmp_path, port)
    lines = {}
    for extra in (("--check",), ()):
        daemon = run_daemon(tmp_path, cfg, *extra)
        try:
            got = daemon.wait(120)
        finally:
            daemon.kill()
        line = one_error_line(daemon.stderr(), "run --check" if extra else "run")
        assert got == code and re.search(message, line), line
        lines[extra] = line.split(": error: ", 1)[1]
    assert lines[("--check",)] == lines[()]


def test_run_check_passes_a_good_config_and_warns_about_an_absent_camera(tmp_path, port):
    calib = tmp_path / "calib.yaml"
    calib.write_text("focal_px: 200.0\nbaseline_m: 0.063\nwidth: 320\nheight: 240\n")
    (tmp_path / "params.yaml").write_bytes(GOOD)
    cfg = config(port, tmp_path / "params.yaml", source={"kind": "uvc", "device": "/dev/video97", "width": 320,
                                                          "height": 240}, calibration=str(calib))
    daemon = run_daemon(tmp_path, cfg, "--check")
    code = daemon.wait(120)
    out = daemon.proc.stdout.read().decode()
    daemon.kill()
    assert code == 0, daemon.stderr()
    assert f"checked: parameters {tmp_path / 'params.yaml'}: hash {PARAMS_64.hash()}, measure a test render" in out
    assert "warning: camera /dev/video97 is not present now" in out and "config valid:" in out


# -- while flying: a bad new file keeps the last good parameters --------------------------------------

@pytest.fixture(scope="module")
def flying(tmp_path_factory):
    """One daemon flying PARAMS_64 for the reload tests, with its peer."""
    d = tmp_path_factory.mktemp("flying")
    rx = Receiver()
    (d / "params.yaml").write_bytes(GOOD)
    daemon = run_daemon(d, config(rx.port, d / "params.yaml"))
    try:
        daemon.wait_for(lambda: "ready:" in daemon.stderr(), 180, "READY")
        yield d, rx, daemon
    finally:
        if daemon.proc.poll() is None:
            daemon.proc.send_signal(signal.SIGTERM)
            daemon.proc.wait(30)
        daemon.kill()
        rx.close()


def _replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".new")
    tmp.write_bytes(data)
    os.replace(tmp, path)


RELOAD_FAULTS = [
    pytest.param(b"sgbm:\n  p1: 600  # caf\xe9\n", r"parameter file is not UTF-8 text", id="not-utf8"),
    pytest.param(b"", r"must set at least one section", id="empty"),
    pytest.param(b"sgbm:\n  p1: 600\n  p1: 900\n", r"sgbm\.p1 is given twice", id="duplicate-key"),
    pytest.param(_params_with(**{"sgbm.p2": 40000}), r"sgbm\.p2 must be at most 32767", id="p2-over-16-bit-costs"),
    pytest.param(_params_with(**{"sgbm.num_disparities": 224, "sgbm.block_size": 31}),
                 r"must measure a test render", id="search-range-hides-the-roi"),
    pytest.param(b"\x00\x01\x02\x03", r"parameter file is a binary file", id="binary"),
    pytest.param(alias_bomb(), r"parameter file uses a YAML anchor \('l0'\) at line 1", id="alias-bomb"),
    pytest.param(THREE_WAY_100, r"sgbm\.uniqueness_ratio must be at most 99 with sgbm\.mode sgbm_3way",
                 id="3way-uniqueness-100"),
    pytest.param(OVERSIZE_PARAMS, r"parameter file is \d+ bytes, more than the 64 KiB", id="over-the-size-cap"),
]


@pytest.mark.parametrize("data,message", RELOAD_FAULTS)
def test_a_bad_new_parameter_file_keeps_the_last_good_and_the_daemon_flies(flying, data, message):
    d, rx, daemon = flying
    kept = f"uav-depth: params rejected, kept {PARAMS_64.hash()[:8]}"
    before = len(daemon.stderr().splitlines())
    t_replace = time.monotonic()
    _replace(d / "params.yaml", data)
    daemon.proc.send_signal(signal.SIGHUP)      # systemctl kill -s HUP, as the docs recommend
    daemon.wait_for(lambda: any(re.search(message, ln) for ln in daemon.stderr().splitlines()[before:]
                                if "parameters rejected, keeping " + PARAMS_64.hash() in ln), 60, "the rejection")
    assert rx.wait(lambda: kept in rx.texts(), timeout=10)
    daemon.proc.send_signal(signal.SIGHUP)      # the same file again: judged once, said once
    t = time.monotonic()
    assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR", since=t)) >= 10, timeout=10), "the messages stopped"
    err = daemon.stderr()
    assert daemon.proc.poll() is None and "Traceback" not in err
    assert "parameters reloaded" not in err
    rejections = [ln for ln in err.splitlines()[before:] if "parameters rejected" in ln]
    assert len(rejections) == 1, rejections
    assert sum(m.text == kept for m in rx.of("STATUSTEXT", since=t_replace)) == 1


def test_a_half_written_file_is_never_loaded(flying):
    d, rx, daemon = flying
    half = b"sgbm:\n  num_disparities: 32\n"
    full = half + b"  block_size: 7\nwls:\n  lambda: 9000.0\n"
    half_hash = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32}).hash()
    full_hash = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 32, "sgbm.block_size": 7,
                                          "wls.lambda": 9000.0}).hash()
    with open(d / "params.yaml", "wb") as fh:     # written in place, in two parts, 3 s apart
        fh.write(half)
        fh.flush()
        os.fsync(fh.fileno())
        daemon.proc.send_signal(signal.SIGHUP)
        time.sleep(3.0)
        assert not any(half_hash[:8] in t for t in rx.texts()), "the half file was loaded"
        fh.write(full[len(half):])
    assert rx.wait(lambda: f"uav-depth: params {full_hash[:8]} loaded" in rx.texts(), timeout=60), \
        daemon.stderr()[-3000:]
    assert not any(half_hash[:8] in t for t in rx.texts())
    assert half_hash not in daemon.stderr() and "Traceback" not in daemon.stderr()


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


# -- replay, signing key path, free space -------------------------------------------------------------

def test_a_replay_frame_whose_meta_is_not_utf8_is_one_line_and_the_replay_ends(tmp_path, port):
    cfg = SceneConfig(**SCENE)
    writer = SessionWriter(tmp_path / "log", cfg.calibration)
    scene = Scene(cfg)
    for i in range(3):
        frame = scene.render(rng=np.random.default_rng(i))
        writer.write(i, frame.left, frame.right, meta={"time_s": 0.2 * i, "branch_distance_m": 0.8})
    bad = writer.session.frames()[1]
    bad.meta_path.write_bytes(b'{"time_s": 0.2, "note": "caf\xe9"}')
    (tmp_path / "params.yaml").write_bytes(GOOD)
    daemon = run_daemon(tmp_path, config(port, tmp_path / "params.yaml",
                                         source={"kind": "replay", "path": str(tmp_path / "log"), "rate_hz": 2}))
    try:
        code = daemon.wait(180)      # ends by itself: not a lost camera, not a restart loop
    finally:
        daemon.kill()
    err = daemon.stderr()
    assert code == 0 and "Traceback" not in err, err[-3000:]
    skipped = [ln for ln in err.splitlines() if "skipping" in ln]
    assert len(skipped) == 1 and "frame metadata is not UTF-8 text" in skipped[0], err[-3000:]
    assert "camera lost" not in err and "frames delivered" in err


def test_a_relative_signing_key_file_is_found_beside_the_config(tmp_path):
    rx = Receiver()
    rx.conn.setup_signing(bytes.fromhex(KEY_HEX.decode().strip()), sign_outgoing=False)
    conf = tmp_path / "etc"
    elsewhere = tmp_path / "elsewhere"
    conf.mkdir()
    elsewhere.mkdir()
    (conf / "params.yaml").write_bytes(GOOD)
    (conf / "mavlink.key").write_bytes(KEY_HEX)
    os.chmod(conf / "mavlink.key", 0o600)
    cfg = config(rx.port, "params.yaml", mavlink={"signing_key_file": "mavlink.key"})
    daemon = run_daemon(conf, cfg, cwd=elsewhere)
    try:
        assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR")) >= 3, timeout=180), daemon.stderr()[-3000:]
        daemon.proc.send_signal(signal.SIGTERM)
        code = daemon.wait(60)
    finally:
        daemon.kill()
        rx.close()
    assert code == 0, daemon.stderr()[-3000:]
    signed = [m for m in rx.of("DISTANCE_SENSOR") if m.get_signed()]
    assert signed, "messages are not signed"


def test_frame_logging_stops_at_the_free_space_floor_and_the_daemon_flies_on(tmp_path):
    rx = Receiver()
    logs = tmp_path / "logs"
    (tmp_path / "params.yaml").write_bytes(GOOD)
    # A floor above any disk's free space: the first frame would take the disk below it.
    cfg = config(rx.port, tmp_path / "params.yaml", logging={"dir": str(logs), "every_n": 1, "min_free_mb": 1e9})
    daemon = run_daemon(tmp_path, cfg)
    try:
        daemon.wait_for(lambda: "frame logging stopped: free space" in daemon.stderr(), 180, "logging to stop")
        t = time.monotonic()
        assert rx.wait(lambda: len(rx.of("DISTANCE_SENSOR", since=t)) >= 10, timeout=10)
        daemon.proc.send_signal(signal.SIGTERM)
        code = daemon.wait(60)
    finally:
        daemon.kill()
        rx.close()
    err = daemon.stderr()
    assert code == 0 and "Traceback" not in err
    assert "below logging.min_free_mb 1e+09 MB" in err
    assert not list(logs.rglob("*_left.png"))
    assert any("logging stopped" in t for t in rx.texts())
