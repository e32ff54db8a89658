"""The real daemon process for the link fault tests (`uav-depth run`, synthetic source), and waiting on it."""

import os
import subprocess
import sys
import time

import yaml

from uav_depth.core.params import DEFAULT_PARAMS, save_params


MAX_AGE_MS = 450.0
SCENE = {"width": 320, "height": 240, "focal_px": 200.0, "branch_distance_m": 0.8, "branch_radius_m": 0.04,
         "seed": 1}


class Daemon:
    """``uav-depth run`` as a subprocess; stops by SIGTERM (or kill) in ``close``."""

    def __init__(self, tmp_path, url, **sections):
        params = tmp_path / "params.yaml"
        save_params(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64}), params)
        cfg = {"source": {"kind": "synthetic", "fps": 10, "scene": SCENE}, "params_file": str(params),
               "ranging": {"max_age_ms": MAX_AGE_MS}, "mavlink": {"url": url, "rate_hz": 20},
               "service": {"status_interval_s": 1.0}}
        for k, v in sections.items():
            cfg[k] = {**cfg.get(k, {}), **v}
        path = tmp_path / "run.yaml"
        path.write_text(yaml.safe_dump(cfg))
        self.stderr_path = tmp_path / "daemon.stderr"
        self.proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(path)],
                                     stdout=subprocess.DEVNULL, stderr=open(self.stderr_path, "w"),
                                     env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})

    def rss_kb(self) -> int:
        with open(f"/proc/{self.proc.pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))

    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def wait_for(pred, timeout, daemon, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return
        assert daemon.proc.poll() is None, f"daemon exited ({daemon.proc.returncode}) waiting for {what}: " \
                                           f"{daemon.stderr()[-2000:]}"
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}: {daemon.stderr()[-2000:]}")
