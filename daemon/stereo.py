"""The ``stereo`` thread: the newest frame through the current stage to an estimate.

Rectify, run the disparity pipeline and the ranging of the current
:class:`~uav_depth.daemon.stage.Stage` (read once per frame, so a parameter swap lands
between frames), gate single-frame jumps, publish the :class:`~uav_depth.daemon.estimate.Estimate`
by one assignment and wake the send clock; then offer the frame (references only) to the
live view, the rig check, the OBSTACLE_DISTANCE pass and the frame logger. Nobody waits on it.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from uav_depth.core.errors import ConfigError, FrameError
from uav_depth.daemon.assembly import Fitted
from uav_depth.daemon.capture import Mailbox
from uav_depth.daemon.config import RunConfig
from uav_depth.daemon.framelog import frame_meta
from uav_depth.core.ranging import OutlierGate
from uav_depth.daemon.estimate import Estimate
from uav_depth.daemon.sources import Frame
from uav_depth.daemon.stage import Stage, StageHolder
from uav_depth.daemon.state import ServiceState

log = logging.getLogger("uav_depth.service")


class StereoLoop:
    """The ``stereo`` thread: frames from the mailbox through the current stage to an estimate.

    It writes the shared state's stereo fields and owns the outlier gate: a camera loss
    (``camera_losses`` moving, written by the capture thread) resets the gate here, so the
    gate is never touched from two threads.
    """

    def __init__(self, config: RunConfig, state: ServiceState, mailbox: Mailbox, stages: StageHolder,
                 fitted: Fitted, t0: float):
        self.config, self.state, self.mailbox, self.stages, self.fitted, self.t0 = (config, state, mailbox, stages,
                                                                                    fitted, t0)
        cfg = config
        self.gate = OutlierGate(cfg.ranging.max_jump_rel, cfg.ranging.confirm_frames,
                                forget_s=max(1.0, 2 * cfg.ranging.max_age_ms / 1000.0))
        self._losses = 0
        self._thread = threading.Thread(target=self.run, name="stereo", daemon=True)

    def start(self) -> "StereoLoop":
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        """The loop runs (it ends only at shutdown, or when the first frames cannot be processed)."""
        return self._thread.is_alive()

    def join(self, timeout_s: float) -> bool:
        if self._thread.ident is not None:
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def run(self) -> None:
        st = self.state
        while not st.stopping.is_set():
            frame = self.mailbox.get(0.2)
            if frame is None:
                continue
            try:
                self.process(frame)
            except FrameError as exc:
                if not st.first_frame.is_set():
                    st.startup_error = ConfigError("calibration", "must match the frames", str(exc))
                    return
                log.error("frame %d skipped: %s", frame.index, exc)
            except Exception:   # keep flying: one bad frame must not end the stereo loop
                log.exception("frame %d failed", frame.index)
            finally:
                st.busy_since = None
                st.frames_done += 1

    def process(self, frame: Frame) -> None:
        st, f = self.state, self.fitted
        stage = self.stages.stage        # one read: a swap lands between frames, never inside one
        assert stage is not None
        if st.camera_losses != self._losses:
            self._losses = st.camera_losses
            self.gate.reset()            # what was seen before the loss says nothing about now
        t_start = time.monotonic()
        st.busy_since = t_start
        left, right = f.rectifier(frame.left, frame.right)
        t_rect = time.monotonic()
        result = stage.pipeline.run(left, right)
        t_disp = time.monotonic()
        m = self.gate.near(stage.ranger.measure(result), stage.ranger.limits.min_distance_m, frame.t_capture)
        t_done = time.monotonic()
        timings = {"queue": (t_start - frame.t_capture) * 1e3, "rectify": (t_rect - t_start) * 1e3,
                   "disparity": (t_disp - t_rect) * 1e3, "ranging": (t_done - t_disp) * 1e3,
                   "latency": (t_done - frame.t_capture) * 1e3}
        est = Estimate(m, stage.ranger.limits, frame.t_capture, t_done, frame.index, stage.hash, frame.truth_m,
                       timings, too_close=m.too_close)
        st.last_estimate = est
        if not m.valid or self.gate.accept(m.distance_m, frame.t_capture):
            st.estimate = est     # nothing measured or too close (never held back), or an accepted reading
        # else: a single-frame jump, held back; the previous estimate ages out on its own
        f.clock.notify()          # sent now, not at the next tick
        st.stats.add(t_done, timings)
        self.offer(f, frame, left, right, result, est, stage)
        st.first_frame.set()

    def offer(self, f: Fitted, frame: Frame, left: Any, right: Any, result: Any, est: Estimate,
              stage: Stage) -> None:
        """The frame to the optional consumers: references only, none of them waits."""
        if f.liveview is not None:       # nothing is drawn unless someone watches
            f.liveview.offer(left, result.disparity, est, f.roi, stage.params)
        if f.rigwatch is not None:
            f.rigwatch.offer(left, right)
        if f.obstacles is not None:
            f.obstacles.offer(left, right, frame.t_capture)
        if f.framelog is not None:
            f.framelog.consider(frame.index, left, right,
                                frame_meta(frame, est, self.t0, self.config.source_kind, f.roi),
                                frame.reference, frame.reference_source)
