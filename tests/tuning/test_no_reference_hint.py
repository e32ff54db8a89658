"""tune on a log without references points to reference import and --metric selfsup (one line)."""

import cv2
import numpy as np

from uav_depth.cli.exit_codes import EXIT_ERROR
from uav_depth.cli.main import main
from uav_depth.core.calibration import Calibration
from uav_depth.core.session import SessionWriter


def test_tune_without_references_says_what_to_do(tmp_path, capsys):
    rng = np.random.default_rng(0)
    w = SessionWriter(tmp_path / "s", Calibration(focal_px=100.0, baseline_m=0.06, width=96, height=64))
    img = rng.integers(0, 255, (64, 96), dtype=np.uint8)
    w.write(0, img, np.roll(img, -4, axis=1))
    code = main(["tune", str(tmp_path / "s"), "--generations", "1"])
    err = capsys.readouterr().err
    assert code == EXIT_ERROR and err.count("\n") == 1
    assert "reference import" in err and "--metric selfsup" in err
