"""The Ray backend: a small tune on a local Ray of 2 CPUs gives exactly the serial result."""

import pytest

from uav_depth.tuning.executor import RayExecutor, SerialExecutor
from uav_depth.tuning.store import RunStore
from uav_depth.tuning.study import Study, StudyConfig

from .conftest import TINY_BASE

ray = pytest.importorskip("ray", reason="the ray extra is not installed")


def test_ray_backend_runs_a_small_tune_identical_to_serial(tiny_frames):
    config = StudyConfig(optimizer="ga", population=6, generations=3, seed=9)
    framesets = {"train": tiny_frames}
    with SerialExecutor(framesets, "mse") as ex:
        serial_store = RunStore()
        serial = Study(config, tiny_frames, ex, serial_store, TINY_BASE).run()
    with RayExecutor(framesets, "mse", workers=2, address="local") as ex:
        assert ex.kind == "ray" and ex.workers == 2
        ray_store = RunStore()
        on_ray = Study(config, tiny_frames, ex, ray_store, TINY_BASE).run()
    assert not ray.is_initialized()          # the executor shut down the Ray it started
    assert on_ray.runs[0].best_key == serial.runs[0].best_key
    assert on_ray.runs[0].history == serial.runs[0].history
    assert ray_store.trials() == serial_store.trials()
    assert on_ray.evaluated == serial.evaluated > 0
