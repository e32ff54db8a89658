"""uav-depth check-rig on a session and on live frames from a run config (real subprocesses)."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from uav_depth.cli.exit_codes import EXIT_CANNOT_TELL, EXIT_CONFIG, EXIT_MISALIGNED
from uav_depth.core.calibration import Calibration
from uav_depth.core.session import SessionWriter
from uav_depth.sim.scene import Scene, SceneConfig


def cli(*args):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *args], capture_output=True, text=True,
                          timeout=300)


def session(path, dy, frames=2):
    cfg = SceneConfig(width=480, height=270, focal_px=260.0, branch_distance_m=1.5, seed=9)
    w = SessionWriter(path, Calibration(focal_px=260.0, baseline_m=0.063, width=480, height=270))
    for i in range(frames):
        fr = Scene(cfg).render(rng=np.random.default_rng(9 + i))
        m = np.float32([[1, 0, 0], [0, 1, dy]])
        right = cv2.warpAffine(fr.right, m, (480, 270), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        w.write(i, fr.left, right)
    return path


@pytest.mark.parametrize("dy, code, word", [(0.0, 0, "OK"), (1.0, EXIT_MISALIGNED, "MISALIGNED")],
                         ids=["aligned", "1px-off"])
def test_session(tmp_path, dy, code, word):
    out = cli("check-rig", str(session(tmp_path / "s", dy)))
    assert out.returncode == code, out.stderr
    assert out.stdout.startswith("2 frame(s) 480x270: " + word)
    median = float(out.stdout.split("vertical misalignment ")[1].split(" px")[0])
    assert abs(median - dy) <= 0.1


def test_live_frames_from_a_run_config(tmp_path):
    cfg = {"source": {"kind": "synthetic", "fps": 20,
                      "scene": {"width": 480, "height": 270, "focal_px": 260.0, "seed": 2}}}
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(cfg))
    out = cli("check-rig", "--config", str(tmp_path / "run.yaml"), "--frames", "2")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("2 frame(s) 480x270: OK")


def test_blank_frames_cannot_tell(tmp_path):
    w = SessionWriter(tmp_path / "s", Calibration(focal_px=100.0, baseline_m=0.06, width=120, height=100))
    w.write(0, np.full((100, 120, 3), 90, np.uint8), np.full((100, 120, 3), 90, np.uint8))
    out = cli("check-rig", str(tmp_path / "s"))
    assert out.returncode == EXIT_CANNOT_TELL and "cannot tell" in out.stdout


def test_not_a_session_is_one_line(tmp_path):
    out = cli("check-rig", str(tmp_path))
    assert out.returncode == EXIT_CONFIG
    assert out.stderr.count("\n") == 1 and "session" in out.stderr and "Traceback" not in out.stderr
