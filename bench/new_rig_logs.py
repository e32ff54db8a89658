"""The daemon's own frame log as a tuning log, for bench/new_rig.py ``--logs daemon``.

One flight per seed: ``uav-depth run`` on the synthetic source at the rig, approaching a branch from 2.5 m at
0.25 m/s (every other flight a leafy scene), frame logging on (every frame it ranges), stopped with SIGTERM once
enough frames are logged. A real flight logs no reference disparity and no truth, so both are removed: the log
is what a user tunes on with ``--metric selfsup``.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from uav_depth.core.session import find_sessions
from uav_depth.sim.scene_config import SceneConfig

#: The longest one flight may take to log its frames (a 1920x1080 frame renders in seconds on 2 cores).
FLIGHT_TIMEOUT_S = 900.0
LEAFY_KEYS = ("twigs", "fascicles", "small_branches", "sky_fraction", "shadow_strength", "right_gain",
              "right_offset", "noise_std", "blur_sigma", "right_blur_sigma", "rect_error_px")


def flight_config(rig, seed: int, logdir: Path) -> dict:
    """The run config of one logged flight at ``rig``."""
    scene = {"width": rig.width, "height": rig.height, "focal_px": rig.focal_px, "baseline_m": rig.baseline_m,
             "branch_distance_m": 2.5, "seed": seed}
    if seed % 2 == 1:
        leafy = SceneConfig.leafy(seed=seed)
        scene.update({k: getattr(leafy, k) for k in LEAFY_KEYS})
    scene.update(rig.camera)
    return {"source": {"kind": "synthetic", "fps": 2.0, "approach_speed_mps": 0.25, "stop_distance_m": 0.5,
                       "scene": scene},
            "params_file": str(rig.base_file()),
            "ranging": {"max_distance_m": 7.0},
            "logging": {"dir": str(logdir), "every_n": 1},
            "mavlink": {"url": "udpout:127.0.0.1:14599", "system_id": 1, "component_id": 191}}


def _logged(logdir: Path, before: set[str]) -> int:
    new = [s for s in find_sessions(logdir) if s.path.name not in before] if any(logdir.iterdir()) else []
    return sum(len(s.frames()) for s in new)


def fly(rig, seed: int, logdir: Path, frames: int, work: Path) -> None:
    """One flight, until ``frames`` frames are logged (or the timeout)."""
    cfg_path = work / f"flight-{seed}.yaml"
    cfg_path.write_text(yaml.safe_dump(flight_config(rig, seed, logdir), sort_keys=False))
    before = {p.name for p in logdir.iterdir()}
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(cfg_path),
                             "--log-level", "warning"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + FLIGHT_TIMEOUT_S
    while proc.poll() is None and time.monotonic() < deadline and _logged(logdir, before) < frames:
        time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    if _logged(logdir, before) < frames:
        raise SystemExit(f"flight {seed} logged {_logged(logdir, before)} of {frames} frames: {err[-2000:]}")


def strip_truth(logdir: Path) -> None:
    """Remove what a real flight does not log: the reference disparity and the truth of each frame."""
    for session in find_sessions(logdir):
        for p in list(session.frames_dir.glob("*_ref.*")) + list(session.frames_dir.glob("*_branch.npy")):
            p.unlink()
        for meta in session.frames_dir.glob("*_meta.json"):
            doc = json.loads(meta.read_text())
            doc.pop("branch_distance_m", None)
            meta.write_text(json.dumps(doc))


def daemon_logs(root: Path, rig, seeds: list[int], frames: int) -> Path:
    """The log directory of one flight per seed (reused when complete)."""
    logdir, done = root / "log", root / "complete"
    if done.exists():
        return logdir
    logdir.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        fly(rig, seed, logdir, frames, root)
    strip_truth(logdir)
    done.write_text("\n".join(s.path.name for s in find_sessions(logdir)))
    return logdir
