"""Rig check: synthetic vertical shifts of 0.5 and 1 px are read within 0.1 px; a correct rig passes."""

import functools

import cv2
import numpy as np
import pytest

from uav_depth.core.errors import FrameError
from uav_depth.core.rigcheck import MAX_VERTICAL_PX, MIN_MATCHES, check_rig, summarise
from uav_depth.sim.scene import Scene, SceneConfig


@functools.lru_cache(maxsize=None)
def _pair():
    cfg = SceneConfig(width=640, height=360, focal_px=350.0, branch_distance_m=1.5, seed=11)
    fr = Scene(cfg).render(rng=np.random.default_rng(11))
    return fr.left, fr.right


def shifted(img, dy, angle_deg=0.0):
    """``img`` moved down by ``dy`` px (bilinear), optionally rotated about its centre."""
    h, w = img.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), angle_deg, 1.0)
    m[1, 2] += dy
    return cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def test_a_correct_rig_passes():
    left, right = _pair()
    c = check_rig(left, right)
    assert c.ok is True, c.verdict()
    assert abs(c.vertical_median_px) < 0.1 and c.n_matches >= MIN_MATCHES
    assert c.verdict().startswith("OK")
    # the horizontal offset is the scene's disparity: positive, inside what the renderer drew
    left_disp = _truth_disparity()
    assert np.nanpercentile(left_disp, 1) - 0.5 <= c.horizontal_median_px <= np.nanpercentile(left_disp, 99) + 0.5


@functools.lru_cache(maxsize=None)
def _truth_disparity():
    cfg = SceneConfig(width=640, height=360, focal_px=350.0, branch_distance_m=1.5, seed=11)
    return Scene(cfg).render(rng=np.random.default_rng(11)).disparity


@pytest.mark.parametrize("dy", [0.5, 1.0, -0.5], ids=["down-0.5px", "down-1px", "up-0.5px"])
def test_vertical_shift_is_read_within_a_tenth_of_a_pixel(dy):
    left, right = _pair()
    c = check_rig(left, shifted(right, dy))
    assert abs(c.vertical_median_px - dy) <= 0.1, c.verdict()
    assert c.vertical_spread_px < 0.25   # bilinear resampling at half a pixel blurs the right image a little


def test_one_pixel_fails_the_rig():
    left, right = _pair()
    c = check_rig(left, shifted(right, 1.0))
    assert c.ok is False and c.verdict().startswith("MISALIGNED")


def test_a_rotation_shows_in_the_corners():
    left, right = _pair()
    c = check_rig(left, shifted(right, 0.0, angle_deg=0.3))   # 0.3 deg: +-1.7 px at the left and right edges
    tl, tr, bl, br = c.vertical_corners_px
    assert tl * tr < 0 and abs(tl - tr) > 2.5 and abs(bl - br) > 2.5, c.vertical_corners_px
    assert c.ok is False


def test_textureless_pair_cannot_tell():
    flat = np.full((200, 300), 128, np.uint8)
    c = check_rig(flat, flat)
    assert c.ok is None and "cannot tell" in c.verdict()


def test_tiny_or_mismatched_images_are_frame_errors():
    with pytest.raises(FrameError, match="too small"):
        check_rig(np.zeros((8, 8), np.uint8), np.zeros((8, 8), np.uint8))
    with pytest.raises(FrameError, match="differ in size"):
        check_rig(np.zeros((100, 100), np.uint8), np.zeros((100, 120), np.uint8))


def test_threshold_is_what_it_says():
    rows = np.column_stack([np.linspace(0, 600, 50), np.linspace(0, 300, 50), np.full(50, 5.0), np.full(50, 0.4)])
    assert summarise(rows, 640, 360).ok is True and MAX_VERTICAL_PX >= 0.4
    assert summarise(rows, 640, 360, threshold_px=0.3).ok is False
