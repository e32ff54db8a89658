"""tuning.imaging: a log's sensor noise and the eyes' gains, measured, so the safety sweep is rendered alike."""

from __future__ import annotations

import numpy as np
import pytest

from uav_depth.cli.tune_sweep import at_imaging
from uav_depth.sim.scene import Scene, SceneConfig
from uav_depth.sim.sweep import quick_sweep
from uav_depth.tuning.frames import FrameData
from uav_depth.tuning.imaging import Imaging, estimate


def _frames(**camera) -> list[FrameData]:
    out = []
    for seed in (1, 2, 3):
        cfg = SceneConfig(width=320, height=240, focal_px=250.0, seed=seed, blur_sigma=1.0, **camera)
        f = Scene(cfg).render(rng=np.random.default_rng(seed))
        out.append(FrameData(f"s/{seed}", f.left, f.right))
    return out


@pytest.mark.parametrize("noise", [2.0, 6.0])
def test_the_sensor_noise_and_the_right_eyes_gain_are_measured_from_the_frames(noise):
    got = estimate(_frames(noise_std=noise, right_gain=1.2, right_offset=-5.0))
    assert got.noise_std == pytest.approx(noise, abs=0.6)
    assert got.right_gain == pytest.approx(1.2, abs=0.05)
    assert estimate([]) is None


def test_the_sweep_takes_the_logs_imaging_only_where_its_scenes_do_not_already_render_it():
    items = list(quick_sweep(320, 240, 250.0, 0.063))
    same, changes = at_imaging(items, Imaging(noise_std=2.5, right_gain=1.0, right_offset=0.0))
    assert changes == {} and same == items                      # within the scenes' own: the sweep as measured
    noisy, changes = at_imaging(items, Imaging(noise_std=6.04, right_gain=1.0, right_offset=0.0))
    assert changes == {"noise_std": 6.0} and {c.noise_std for _, c in noisy} == {6.0}
    assert [k for k, _ in noisy] == [k for k, _ in items]
    _, changes = at_imaging(items, Imaging(noise_std=2.0, right_gain=1.4, right_offset=3.0))
    assert changes == {"right_gain": 1.4, "right_offset": 3.0}
    assert at_imaging(items, None) == (items, {})
