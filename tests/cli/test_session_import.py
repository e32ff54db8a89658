"""uav-depth session import: a folder of stereo pairs becomes a session the other commands read."""

import cv2
import numpy as np
import pytest

from uav_depth.cli.exit_codes import EXIT_CANTCREAT, EXIT_CONFIG, EXIT_ERROR
from uav_depth.cli.main import main
from uav_depth.core.calibration import Calibration, save_calibration
from uav_depth.core.session import Session


def img(seed, w=96, h=64):
    return np.random.default_rng(seed).integers(0, 255, (h, w), dtype=np.uint8)


def write(path, a):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), a)


@pytest.mark.parametrize("layout", ["folders", "suffixes", "per-scene"])
def test_layouts_become_a_session(tmp_path, capsys, layout):
    src = tmp_path / "pairs"
    for i, name in enumerate(["b", "a"]):
        l, r = img(2 * i), img(2 * i + 1)
        if layout == "folders":
            write(src / "left" / f"{name}.png", l), write(src / "right" / f"{name}.png", r)
        elif layout == "suffixes":
            write(src / f"{name}_left.png", l), write(src / f"{name}_right.png", r)
        else:
            write(src / name / "view1.png", l), write(src / name / "view5.png", r)
    out = tmp_path / "s"
    assert main(["session", "import", str(src), str(out), "--focal-px", "80", "--baseline-m", "0.06"]) == 0
    assert "imported 2 pairs 96x64" in capsys.readouterr().out
    s = Session(out)
    frames = s.frames()
    assert [f.load_meta()["name"] for f in frames] == ["a", "b"]                 # name order
    left, right = frames[0].load_pair()
    assert np.array_equal(left, img(2)) and np.array_equal(right, img(3))       # "a" was written second
    c = s.calibration()
    assert (c.width, c.height, c.focal_px, c.baseline_m) == (96, 64, 80.0, 0.06)


def test_calibration_file_must_match_the_size(tmp_path, capsys):
    src = tmp_path / "pairs"
    write(src / "x_left.png", img(0)), write(src / "x_right.png", img(1))
    cal = tmp_path / "cal.yaml"
    save_calibration(Calibration(focal_px=80.0, baseline_m=0.06, width=640, height=480), cal)
    assert main(["session", "import", str(src), str(tmp_path / "s"), "--calibration", str(cal)]) == EXIT_CONFIG
    assert "640x480 but the pairs are 96x64" in capsys.readouterr().err
    save_calibration(Calibration(focal_px=80.0, baseline_m=0.06, width=96, height=64), cal)
    assert main(["session", "import", str(src), str(tmp_path / "s"), "--calibration", str(cal)]) == 0


def test_refusals_are_one_line(tmp_path, capsys):
    src = tmp_path / "pairs"
    write(src / "x_left.png", img(0))
    args = ["session", "import", str(src), str(tmp_path / "s"), "--focal-px", "80", "--baseline-m", "0.06"]
    assert main(args) == EXIT_CONFIG and "without x_right.png" in capsys.readouterr().err
    write(src / "x_right.png", img(1, w=100))
    assert main(args) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "one size" in err and not (tmp_path / "s").exists()
    write(src / "x_right.png", img(1))
    assert main(args) == 0
    assert main(args) == EXIT_CANTCREAT and "--overwrite" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    assert main(["session", "import", str(tmp_path / "empty_nothing"), str(tmp_path / "t"), "--focal-px", "1",
                 "--baseline-m", "1"]) == EXIT_CONFIG
