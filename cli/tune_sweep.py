"""tune's safety sweep rendered at a log's rig, once per rig: a session in the log layout kept in a cache
directory, so the next tune on the same rig reads it instead of rendering it again.

The renders are the sweep's cost (about 0.4 s of one core a frame at 640x360, 330 frames), so they run on the
tune's workers, frame by frame on the terminal. A cache entry is named by the rig, the sweep and a digest of
every scene's configuration, the simulator's source and the numpy and OpenCV versions: whatever would change a
pixel names another entry. An entry is complete when its ``sweep.json`` is written (last); frames already
rendered by an interrupted tune are kept and not rendered again.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import threading
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable

#: What ``--sweep-cache`` defaults to below the user's cache directory ($XDG_CACHE_HOME, else ~/.cache).
CACHE_SUBDIR = "uav-depth/safety-sweep"
INDEX = "sweep.json"


def default_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / CACHE_SUBDIR


def _sim_digest() -> str:
    """A digest of the simulator's source: a renderer change names a new cache entry."""
    import uav_depth.sim as sim

    h = hashlib.sha256()
    for path in sorted(Path(sim.__file__).parent.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def entry_name(sweep: str, items: list, w: int, h: int, focal_px: float, baseline_m: float) -> str:
    """The cache entry of one sweep at one rig (module docstring)."""
    import cv2
    import numpy as np

    blob = json.dumps({"keys": [k for k, _ in items], "scenes": [c.to_dict() for _, c in items],
                       "sim": _sim_digest(), "numpy": np.__version__, "opencv": cv2.__version__},
                      sort_keys=True, default=str)
    digest = hashlib.sha256(blob.encode()).hexdigest()[:12]
    return f"{sweep}-{w}x{h}-f{focal_px:g}-b{baseline_m:g}-{digest}"


def _render_one(path: str, index: int, key: str, cfg) -> tuple[int, float]:
    """Render one sweep frame into the session at ``path``; (index, truth m)."""
    import cv2

    from uav_depth.core.session import SessionWriter
    from uav_depth.sim.sweep import render_with_truth

    cv2.setNumThreads(1)        # the parallelism is across frames
    left, right, truth_m, roi = render_with_truth(cfg)
    SessionWriter(path, cfg.calibration).write(index, left, right,
                                               meta={"branch_distance_m": truth_m, "roi": list(roi), "sweep_key": key})
    return index, truth_m


def _missing(path: Path, n: int) -> list[int]:
    frames = path / "frames"
    return [i for i in range(n) if not (frames / f"{i:06d}_left.png").exists()
            or not (frames / f"{i:06d}_meta.json").exists()]


def _truth(path: Path, index: int) -> float:
    return float(json.loads((path / "frames" / f"{index:06d}_meta.json").read_text())["branch_distance_m"])


def render_sweep(path: Path, items: list, workers: int, progress: Callable[[int, int], None],
                 stop: threading.Event | None, title: str = "the safety sweep") -> None:
    """Render the frames of ``items`` (key, SceneConfig) that ``path`` lacks, on ``workers`` processes."""
    from uav_depth.core.session import SessionWriter
    from uav_depth.tuning.study import TuneInterrupted

    SessionWriter(path, items[0][1].calibration)        # the calibration first: workers only add frames
    todo = _missing(path, len(items))
    done = len(items) - len(todo)
    if not todo:
        return
    if workers <= 1:
        for i in todo:
            if stop is not None and stop.is_set():
                raise TuneInterrupted(f"interrupted while rendering {title} ({done} of {len(items)} "
                                      f"frames are kept in {path})")
            _render_one(str(path), i, *items[i])
            done += 1
            progress(done, len(items))
        return
    import multiprocessing

    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = {pool.submit(_render_one, str(path), i, *items[i]) for i in todo}
        while pending:
            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for f in finished:
                f.result()
                done += 1
                progress(done, len(items))
            if stop is not None and stop.is_set():
                for f in pending:
                    f.cancel()
                raise TuneInterrupted(f"interrupted while rendering {title} ({done} of {len(items)} "
                                      f"frames are kept in {path})")


def safety_frames(sample, sweep: str = "standard", cache: str | None = None, workers: int = 1,
                  phase: Callable[[str], None] = lambda text: None,
                  progress: Callable[[int, int], None] = lambda done, total: None,
                  stop: threading.Event | None = None):
    """The named sweep of uav_depth.sim.sweep (RENDERED: a safety sweep, or ``guide``, the search guide) at the rig
    of ``sample`` (a FrameData of the log: its image size, focal length and baseline) as a
    :class:`~uav_depth.tuning.safety.SweepFrames` in the cache, rendered there when the tune first needs it. ``cache``: the cache directory (None: :func:`default_cache`; "none": a
    temporary directory, removed at exit)."""
    from uav_depth.sim.sweep import RENDERED
    from uav_depth.tuning.safety import SweepFrames

    h, w = sample.left.shape[:2]
    items = list(RENDERED[sweep](w, h, sample.focal_px, sample.baseline_m))
    if cache == "none":
        import atexit
        import shutil

        root = Path(tempfile.mkdtemp(prefix="uav-depth-sweep-"))
        atexit.register(shutil.rmtree, root, True)
    else:
        root = Path(cache) if cache else default_cache()
    path = root / entry_name(sweep, items, w, h, sample.focal_px, sample.baseline_m)
    prefix = "guide" if sweep == "guide" else "sweep"
    title = "the search guide" if sweep == "guide" else "the safety sweep"

    def render() -> list[float]:
        index = path / INDEX
        if index.exists():
            phase(f"{title} at {w}x{h} ({len(items)} frames) from the cache {path}")
        else:
            phase(f"rendering {title} at {w}x{h}, f {sample.focal_px:g} px, B {sample.baseline_m:g} m: "
                  f"{len(items)} frames on {workers} worker(s), kept in {path} for the next tune on this rig")
            path.mkdir(parents=True, exist_ok=True)
            render_sweep(path, items, workers, progress, stop, title)
            doc = {"keys": [k for k, _ in items], "truths": [_truth(path, i) for i in range(len(items))]}
            tmp = path / f".{INDEX}.tmp"
            tmp.write_text(json.dumps(doc))
            os.replace(tmp, index)
        return json.loads(index.read_text())["truths"]

    return SweepFrames(str(path), [f"{i:06d}" for i in range(len(items))], [k for k, _ in items], render, prefix)
