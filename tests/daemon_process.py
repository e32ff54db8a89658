"""The real daemon process for the fault tests (`uav-depth run`, synthetic source, a pymavlink peer on loopback):
its config, its start and the one error line it must end in.
"""

from __future__ import annotations

import functools
import os
import pwd
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from uav_depth.core.params import DEFAULT_PARAMS, dump_params


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


def missing_tool(problem: str):
    """A system tool a test needs is missing: the test skips with the reason on a laptop and fails in CI
    (``CI=true``), where .ci/system-deps installs it."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"{problem}: CI must have it (.ci/system-deps)")
    pytest.skip(problem)


def _nobody_prefix() -> list[str]:
    prefix, problem = _nobody_check()
    if problem is None:
        return prefix
    if problem.startswith("setpriv"):
        missing_tool(problem)
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


def _params_with(**changes) -> bytes:
    return dump_params(PARAMS_64.replace(**changes)).encode()

def alias_bomb(levels: int = 9) -> bytes:
    """Under 1 KB of YAML that expands into 9**levels strings (the "billion laughs")."""
    lines = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return ("\n".join(lines) + "\n").encode()


OVERSIZE_PARAMS = GOOD + b"# padding\n" * 7000      # a valid file, past the 64 KiB cap

#: OpenCV's 3-way matcher dies of SIGFPE at uniqueness 100 (issue 44: params check passed it, run died).
THREE_WAY_100 = _params_with(**{"sgbm.mode": "sgbm_3way"}).replace(b"uniqueness_ratio: 10\n",
                                                                   b"uniqueness_ratio: 100\n")
