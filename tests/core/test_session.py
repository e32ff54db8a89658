import numpy as np
import pytest

from uav_depth.core.errors import FileFormatError
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.core.session import find_sessions, iter_frames, read_disparity, write_disparity


def test_disparity_formats_round_trip(tmp_path):
    disp = np.array([[1.5, np.nan], [30.25, 0.75]], np.float32)
    for suffix in (".npy", ".pfm"):
        back = read_disparity(write_disparity(tmp_path / f"d{suffix}", disp))
        assert np.array_equal(np.isnan(back), np.isnan(disp))
        assert np.allclose(back[~np.isnan(disp)], disp[~np.isnan(disp)])


def test_kitti_png(tmp_path):
    import cv2
    raw = np.array([[0, 256], [512 + 128, 65535]], np.uint16)
    cv2.imwrite(str(tmp_path / "k.png"), raw)
    d = read_disparity(tmp_path / "k.png")
    assert np.isnan(d[0, 0]) and d[0, 1] == 1.0 and d[1, 0] == 2.5


def test_pfm_header_corrupt(tmp_path):
    (tmp_path / "x.pfm").write_bytes(b"P6\n1 1\n255\n\x00")
    with pytest.raises(FileFormatError, match="not a PFM"):
        read_disparity(tmp_path / "x.pfm")


def test_session_written_and_found(tmp_path):
    base = SceneConfig(width=160, height=120, focal_px=100.0)
    write_session(tmp_path / "a", 2, seed=1, base=base)
    write_session(tmp_path / "b", 1, seed=2, base=base)
    assert [s.path.name for s in find_sessions(tmp_path)] == ["a", "b"]
    frames = list(iter_frames(tmp_path, require_reference=True))
    assert [f.key for f in frames] == ["a/000000", "a/000001", "b/000000"]
    left, right = frames[0].load_pair()
    assert left.shape == (120, 160) and frames[0].load_reference().shape == (120, 160)
    assert 0.5 <= frames[0].load_meta()["branch_distance_m"] <= 2.1
    assert find_sessions(tmp_path / "a")[0].calibration().focal_px == 100.0


def test_frames_independent_of_count(tmp_path):
    base = SceneConfig(width=96, height=64, focal_px=60.0)
    write_session(tmp_path / "one", 1, seed=9, base=base)
    write_session(tmp_path / "two", 2, seed=9, base=base)
    a = next(iter_frames(tmp_path / "one")).load_pair()[0]
    b = next(iter_frames(tmp_path / "two")).load_pair()[0]
    assert np.array_equal(a, b)


def test_no_session(tmp_path):
    with pytest.raises(FileFormatError, match="no session found"):
        find_sessions(tmp_path)


def test_fixed_distance_holds_with_fixed_conditions(tmp_path):
    base = SceneConfig(width=160, height=120, focal_px=100.0)
    write_session(tmp_path / "s", 2, seed=1, base=base, vary_scenes=False, fixed_distance=0.7)
    for frame in iter_frames(tmp_path / "s"):
        assert frame.load_meta()["scene"]["branch_distance_m"] == 0.7
