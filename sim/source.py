"""The synthetic source: the foundation's ray-cast tree scene, live, with known truth.

The branch stands at ``scene.branch_distance_m``; the rig may approach it
(``approach_speed_mps`` > 0) or recede (< 0) until ``stop_distance_m``, or follow
any trajectory a ``pose_provider`` gives (SITL: seconds since start -> rig
:class:`~uav_depth.sim.scene.Pose` in the scene's world frame). Every frame
carries its truth (the nearest branch surface in the truth ROI) and the exact
reference disparity.

Rendering a 1280x720 pair costs about half a second, so a pose that did not
change since the last frame is not rendered again: the cached pair is delivered
(same pixels, same noise) with a fresh capture time (a pose provider that says when
its pose was true, ``pose_time``, stamps the frame with that time, and a pose time
already delivered gives no new frame). Frames are paced at ``fps``;
when rendering is slower than that, frames are skipped, never queued.

A camera exposes a frame and delivers it; a ray-cast frame takes tens of
milliseconds to exist. A pose provider that ``predicts`` (the SITL pose tracker) is
asked for the pose at the time the render will be done (the 90th percentile of the
last renders' durations from now), and the frame is stamped with that time and
never delivered before it: it shows the vehicle where it is when the daemon gets
the frame, as a camera with no transfer delay would, so the render's cost is not
counted as the daemon's latency, and a wrong guess shows up as a late frame (its
age at delivery) or as the prediction's error in the reading, never as a frame
from the future.

``read_window`` (a callable, set by whoever knows what reads the frames: ``uav-depth
sitl``) returns the part of the image that anything downstream reads, or None for
all of it; only that part (and the truth ROI) is ray-cast, the rest of the frame is
black (:meth:`~uav_depth.sim.scene.Scene.render`'s ``window``). The flight
pipeline reads its crops only, so at 640x360 this halves the render's cost.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from uav_depth.core.keys import Key, section_values
from uav_depth.core.disparity.near import max_disparity_px, near_params
from uav_depth.core.disparity.window import context_px, window
from uav_depth.core.errors import ConfigError, SourceError
from uav_depth.core.params import StereoParams
from uav_depth.sim.scene import Pose, Scene, SceneConfig, StereoFrame
from uav_depth.core.frames import Frame

PoseProvider = Callable[[float], Pose]

#: Approaching without a stop distance halts the rig this close to the branch.
DEFAULT_APPROACH_STOP_M = 0.25


@dataclass(frozen=True)
class Config:
    """``source:`` keys of the synthetic source (``scene`` is a SceneConfig mapping)."""

    KIND = "synthetic"
    SOURCE_CLASS = "SyntheticSource"      # the class create_source() builds from this config
    KEYS = (
        Key("fps", "float", 15.0, "frames per second delivered", 0.1, 1000.0),
        Key("approach_speed_mps", "float", 0.0, "rig speed toward the branch, m/s (negative recedes)",
            -20.0, 20.0),
        Key("stop_distance_m", "float", None, "the motion stops when the branch is this far (default: "
            f"{DEFAULT_APPROACH_STOP_M} m approaching, 1 m before the background receding)", 0.01, 1000.0,
            optional=True),
        Key("scene", "any", None, "scene keys (uav_depth.sim.scene.SceneConfig: width, height, focal_px, "
            "baseline_m, branch_distance_m, seed, ...); default the 1280x720 ZED-Mini-like scene",
            optional=True, accepts="mapping"),
    )

    scene: SceneConfig = SceneConfig()
    fps: float = 15.0
    approach_speed_mps: float = 0.0
    stop_distance_m: float | None = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | None = None, base_dir: Path | None = None,
                  origin: Mapping[str, str] | None = None) -> "Config":
        values = section_values(cls.KEYS, data, "source", source, origin=origin)
        scene_data = values.pop("scene")
        if scene_data is not None and not isinstance(scene_data, Mapping):
            raise ConfigError("source.scene", "must be a mapping of scene keys", scene_data, source)
        try:
            scene = SceneConfig.from_dict(scene_data, prefix="source.scene")
        except ConfigError as exc:
            if exc.source is None and source is not None:
                raise ConfigError(exc.key, exc.rule, exc.value, source) from exc
            raise
        cfg = cls(scene=scene, **values)
        stop, v, d0 = cfg.stop_distance_m, cfg.approach_speed_mps, scene.branch_distance_m
        if stop is not None and v > 0 and not stop < d0:
            raise ConfigError("source.stop_distance_m", f"must be below scene.branch_distance_m ({d0:g}) when "
                              "approaching", stop, source)
        if stop is not None and v < 0 and not d0 < stop < scene.background_distance_m:
            raise ConfigError("source.stop_distance_m", f"must lie between scene.branch_distance_m ({d0:g}) and "
                              f"the background ({scene.background_distance_m:g}) when receding", stop, source)
        return cfg

    def scripted_distance(self, t_s: float) -> float:
        """Distance to the branch (m, along the optical axis) ``t_s`` seconds after start."""
        d0, v = self.scene.branch_distance_m, self.approach_speed_mps
        if v == 0:
            return d0
        if v > 0:
            stop = self.stop_distance_m if self.stop_distance_m is not None else min(DEFAULT_APPROACH_STOP_M, d0)
            return max(stop, d0 - v * t_s)
        stop = self.stop_distance_m if self.stop_distance_m is not None else self.scene.background_distance_m - 1.0
        return min(stop, d0 - v * t_s)

    def scripted_pose(self, t_s: float) -> Pose:
        """The rig pose of the scripted motion: moved along the optical axis."""
        return Pose.forward(self.scene.branch_distance_m - self.scripted_distance(t_s))


def pipeline_reads(params: StereoParams, width: int, height: int, near: bool = True) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) px of a width x height pair that the flight pipeline reads with ``params``.

    The union of the crops it matches (:func:`uav_depth.core.disparity.window.window`):
    the main pass's (``compute.roi`` plus the search margin), with ``near`` the near
    pass's (:func:`uav_depth.core.disparity.near.near_params`), and the farthest the fine
    pass (``compute.fine_disparities``) can reach for a box inside ``compute.roi``.
    Ranging reads only the maps these produce, inside the ranging ROI.
    """
    crops = [window(params, width, height).crop]
    if near:
        crops.append(window(near_params(params), width, height).crop)
    cp = params.compute
    if cp.fine_pass:
        # The fine pass (core.disparity.fine) re-matches a box inside compute.roi at full resolution:
        # its left crop reaches fine_disparities + context beyond the box, its right crop as far again
        # plus the shift d0, at most the main search's largest disparity.
        rx0, ry0, rx1, ry1 = cp.roi_pixels(width, height)
        context = context_px(params)
        reach = cp.fine_disparities + context
        crops.append((max(0, rx0 - reach - int(math.ceil(max_disparity_px(params)))), max(0, ry0 - context),
                      min(width, rx1 + reach), min(height, ry1 + context)))
    return (min(c[0] for c in crops), min(c[1] for c in crops), max(c[2] for c in crops), max(c[3] for c in crops))


class SyntheticSource:
    """Live synthetic frames. See the module docstring.

    ``pose_provider``: seconds since ``open()`` -> rig Pose; None uses the config's
    scripted motion. ``truth_roi``: (x0, y0, x1, y1) px where the truth is taken
    (the ranging ROI; default the scene's central third). ``clock``: monotonic
    seconds (tests may pass their own).
    """

    kind = "synthetic"

    def __init__(self, config: Config, pose_provider: PoseProvider | None = None,
                 truth_roi: tuple[int, int, int, int] | None = None, clock: Callable[[], float] = time.monotonic,
                 stop_event: threading.Event | None = None):
        self.config = config
        self.pose_provider = pose_provider
        self.truth_roi = tuple(truth_roi) if truth_roi is not None else config.scene.center_roi
        self.clock = clock
        self._stop = stop_event or threading.Event()
        self.calibration = config.scene.calibration
        self._scene: Scene | None = None
        self._cache: tuple[bytes, StereoFrame] | None = None
        self._pose_time: float | None = None
        self.read_window: Callable[[], tuple[int, int, int, int] | None] | None = None
        self._t0 = 0.0
        self._next = 0
        self.renders = 0
        self._render_s: collections.deque[float] = collections.deque(maxlen=16)

    def describe(self) -> str:
        c = self.config
        motion = (f", approaching at {c.approach_speed_mps:g} m/s" if c.approach_speed_mps > 0 else
                  f", receding at {-c.approach_speed_mps:g} m/s" if c.approach_speed_mps < 0 else "")
        who = "pose provider" if self.pose_provider else f"branch at {c.scene.branch_distance_m:g} m{motion}"
        return f"synthetic {c.scene.width}x{c.scene.height} at {c.fps:g} fps, {who}"

    def open(self) -> None:
        if self._scene is None:
            self._scene = Scene(self.config.scene)
        self._t0 = self.clock()
        self._next = 0
        self._render(self._pose(0.0), 0)   # pre-render: the first read is not half a second late

    def close(self) -> None:
        self._cache = None

    def render_lead_s(self) -> float:
        """How long a render is expected to take: the 90th percentile of the last ones (0 before any)."""
        if not self._render_s:
            return 0.0
        xs = sorted(self._render_s)
        return xs[min(len(xs) - 1, int(math.ceil(0.9 * len(xs))) - 1)]

    def _pose(self, t_s: float, at: float | None = None) -> Pose:
        if self.pose_provider is None:
            return self.config.scripted_pose(t_s)
        try:
            if at is not None:
                return self.pose_provider(t_s, at=at)
            return self.pose_provider(t_s)
        except SourceError:
            raise
        except Exception as exc:   # a broken provider is a lost camera, not a crashed daemon
            raise SourceError(f"synthetic: pose provider failed: {type(exc).__name__}: {exc}") from exc

    def window(self) -> tuple[int, int, int, int] | None:
        """The part of the image rendered now: ``read_window()`` grown to hold the truth ROI, or None (all)."""
        want = self.read_window() if self.read_window is not None else None
        if want is None:
            return None
        (x0, y0, x1, y1), (tx0, ty0, tx1, ty1) = want, self.truth_roi
        sc = self.config.scene
        win = (max(0, min(x0, tx0)), max(0, min(y0, ty0)), min(sc.width, max(x1, tx1)), min(sc.height, max(y1, ty1)))
        return None if win == (0, 0, sc.width, sc.height) else win

    def _render(self, pose: Pose, index: int, window: tuple[int, int, int, int] | None = None,
                ) -> tuple[StereoFrame, bool]:
        key = (np.asarray(pose.rotation, np.float64).tobytes() + np.asarray(pose.position, np.float64).tobytes()
               + repr(window).encode())
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1], False
        assert self._scene is not None
        rendered = self._scene.render(pose, np.random.default_rng([self.config.scene.seed, index]), window)
        self._cache = (key, rendered)
        self.renders += 1
        return rendered, True

    def read(self, timeout_s: float) -> Frame | None:
        if self._scene is None:
            raise SourceError("synthetic: read() before open()")
        period = 1.0 / self.config.fps
        # A late reader gets the latest frame due, never a backlog of old ones.
        index = max(self._next, int(math.floor((self.clock() - self._t0) / period)))
        wait = self._t0 + index * period - self.clock()
        if wait > timeout_s:
            self._stop.wait(timeout_s)
            return None
        if wait > 0 and self._stop.wait(wait):
            return None
        t_pose = self.clock()
        window = self.window()
        at = t_pose + self.render_lead_s() if getattr(self.pose_provider, "predicts", False) else None
        rendered, fresh = self._render(self._pose(t_pose - self._t0, at), index, window)
        truth = rendered.nearest_branch_distance(self.truth_roi)
        if fresh:
            self._render_s.append(self.clock() - t_pose)
        # The frame shows the rig where the pose puts it: it is as old as that pose (a SITL pose
        # carries the time the vehicle was there, ``pose_time``, or the time it was predicted for),
        # however long the render took, and a pose already shown is no new frame. A frame is never
        # delivered before the time it shows. A scripted pose is sampled now; its cached pair (the rig
        # at rest) is captured again now.
        pose_time = getattr(self.pose_provider, "pose_time", None)
        if pose_time is not None:
            if pose_time == self._pose_time:
                self._stop.wait(min(timeout_s, period))
                return None
            self._pose_time = pose_time
            early = pose_time - self.clock()
            if early > 0 and self._stop.wait(early):
                return None
            t_capture = pose_time
        else:
            t_capture = t_pose if fresh else self.clock()
        self._next = index + 1
        return Frame(left=rendered.left, right=rendered.right, index=index, t_capture=t_capture,
                     truth_m=None if math.isnan(truth) else truth, reference=rendered.disparity,
                     reference_source={"kind": "synthetic", "exact": True,
                                       "note": "ray-cast ground truth from uav_depth.sim.scene"},
                     meta={"scene_seed": self.config.scene.seed, "rendered": fresh,
                           "window": None if window is None else list(window)})
