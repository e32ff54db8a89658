"""The daemon: one Service with start-up, main loop and shutdown.

Threads and who waits on whom (nobody waits on the stereo stage):

- ``capture`` (:mod:`uav_depth.daemon.capture`): reads the source into a one-slot
  mailbox (the newest frame wins; older ones are dropped, never queued). Camera
  loss: close, reopen with back-off, STATUSTEXT "camera lost" / "camera back".
- ``stereo``: takes the newest frame, rectifies, runs the disparity pipeline and
  ranging of the current :class:`~uav_depth.daemon.stage.Stage`, and publishes an
  :class:`~uav_depth.daemon.ranging.Estimate` by one
  assignment. It reads the current stage (pipeline + ranger) by one attribute
  read per frame, so a parameter swap never interrupts a frame.
- ``mavlink-clock`` (:class:`~uav_depth.daemon.mavlink_out.SendClock`): DISTANCE_SENSOR
  at ``rate_hz``, HEARTBEAT at 1 Hz, from the newest estimate if it is fresh.
- ``mavlink-io``: the link's reader and reconnector; ``params-watch``: hot
  reload; ``frame-logger``: the background writer.
- the caller's thread runs :meth:`Service.run`: start-up, then health checks,
  sd_notify WATCHDOG/STATUS and the status log line (:mod:`uav_depth.daemon.health`)
  until the stop event is set, then a bounded shutdown that says what it abandoned.

This module is the lifecycle; the stage and its reload live in
:mod:`uav_depth.daemon.stage`, what the service reports in :mod:`~uav_depth.daemon.health`,
the frame log's metadata in :mod:`~uav_depth.daemon.framelog`.

Signal handlers (in the CLI) only set events: ``stop``, :meth:`Service.request_log_frame`,
:meth:`Service.request_reload`.

Longer than 400 lines because start-up, the main loop and the bounded shutdown are one lifecycle; stage, capture and health live apart.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError, FrameError, SourceError, UavDepthError
from uav_depth.core.rectify import Rectifier
from uav_depth.daemon.capture import Capture, Mailbox
from uav_depth.daemon.config import RunConfig
from uav_depth.daemon.framelog import FrameLogger, ensure_log_dir, frame_meta
from uav_depth.daemon.health import Health, Stats, status_line
from uav_depth.daemon.liveview import LiveView
from uav_depth.daemon.obstacles import Field, ObstacleSender, encoder, limits_cm
from uav_depth.daemon.rigwatch import RigWatch
from uav_depth.daemon.mavlink_out import (CAMERA_LOST, MEASURING, PARAMS_UNUSABLE, SHUTTING_DOWN, SOURCE_ENDED,
                                          STARTING, MavlinkLink, SendClock)
from uav_depth.daemon.notify import Notifier
from uav_depth.daemon.ranging import Estimate, OutlierGate, RangeLimits, resolve_roi
from uav_depth.daemon.reload import FileWatcher
from uav_depth.daemon.sources import Frame, FrameSource, create_source
from uav_depth.daemon.stage import Stage, StageHolder, resolve_calibration
from uav_depth.daemon.trial import Trials

log = logging.getLogger("uav_depth.service")

@dataclass(frozen=True)
class ShutdownReport:
    duration_s: float
    abandoned: tuple[str, ...] = ()

    @property
    def clean(self) -> bool:
        return not self.abandoned


class Service:
    """The daemon, usable in-process: ``Service(config).run(stop_event)``.

    ``source``: a ready-made (unopened) FrameSource instead of the config's;
    ``pose_provider``: handed to the synthetic source (SITL); ``link``: a
    MavlinkLink to use (else one is built from ``config.mavlink``, available as
    ``service.link`` before ``run`` so callers can subscribe); ``notifier``:
    sd_notify (default: from the environment).
    """

    def __init__(self, config: RunConfig, *, source: FrameSource | None = None,
                 pose_provider: Callable[[float], Any] | None = None, link: MavlinkLink | None = None,
                 notifier: Notifier | None = None):
        self.config = config
        self._stopping = threading.Event()
        kwargs: dict[str, Any] = {"stop_event": self._stopping}
        if pose_provider is not None:
            if config.source_kind != "synthetic":
                raise ConfigError("source.kind", "must be synthetic when a pose provider drives the rig",
                                  config.source_kind)
            kwargs["pose_provider"] = pose_provider
        self.source: FrameSource = source if source is not None else create_source(config.source, **kwargs)
        svc = config.service
        self.link = link if link is not None else MavlinkLink(config.mavlink, svc.reconnect_min_s,
                                                              svc.reconnect_max_s)
        self.notifier = notifier if notifier is not None else Notifier()
        self.health = Health(svc, self.notifier, self.status_line)
        self.stages = StageHolder(config.params_file, config.ranging, self.link.statustext, self._stopping,
                                  Trials(svc.trial_timeout_s))
        self.estimate: Estimate | None = None       # what the send clock reads; replaced by one assignment
        self.last_estimate: Estimate | None = None   # newest frame's result, accepted or not
        self.calibration: Calibration | None = None
        self.rectifier: Rectifier | None = None
        self.roi: tuple[int, int, int, int] | None = None
        self.clock: SendClock | None = None
        self.framelog: FrameLogger | None = None
        self.liveview: LiveView | None = None       # liveview.enabled: the read-only web page
        self.rigwatch: RigWatch | None = None       # rig_check.interval_s > 0: the periodic rig check
        self.obstacles: ObstacleSender | None = None  # obstacle_distance.enabled: OBSTACLE_DISTANCE
        self.state = "boot"
        self.camera_ok = False
        self.ended: str | None = None
        self.t0 = time.monotonic()
        self._mailbox = Mailbox()
        self.frames_done = 0     # frames the stereo stage finished (processed, skipped or failed)
        self.capture = Capture(self.source, svc, self._mailbox, self._stopping, on_lost=self._camera_lost,
                               on_back=self._camera_back, on_end=self._source_ended,
                               in_source=self.health.in_source)
        self._gate = OutlierGate(config.ranging.max_jump_rel, config.ranging.confirm_frames,
                                 forget_s=max(1.0, 2 * config.ranging.max_age_ms / 1000.0))
        self._threads: dict[str, threading.Thread] = {}
        self._first_frame = threading.Event()
        self._startup_error: UavDepthError | None = None
        self._reload_now = threading.Event()
        self._watcher: FileWatcher | None = None

    # -- control from signal handlers (they only set events) -------------------------------------
    def request_log_frame(self) -> None:
        """Log the next processed frame (SIGUSR1)."""
        if self.framelog is not None:
            self.framelog.request()

    def request_reload(self) -> None:
        """Re-read the parameter file now (SIGHUP)."""
        self._reload_now.set()

    # -- what the other parts read -------------------------------------------------------------
    @property
    def stage(self) -> Stage | None:
        """The current stereo stage (pipeline + ranger); replaced as a whole on reload."""
        return self.stages.stage

    @property
    def stats(self) -> Stats:
        return self.health.stats

    @property
    def condition(self) -> str:
        """The one condition that decides what goes on the wire (:mod:`uav_depth.daemon.mavlink_out`).

        ``MEASURING``: frames flow through a stage built from the configured parameters, and each
        estimate then says whether it measured and how old it is (the wire contract decides per
        estimate). Every other value is blind, whatever the newest estimate says:
        ``SHUTTING_DOWN`` once shutdown began; ``STARTING`` before the first frame; ``SOURCE_ENDED``
        when a finite source ended; ``CAMERA_LOST`` while the source is reconnecting;
        ``PARAMS_UNUSABLE`` when the configured parameter file is not what flies (missing, so the
        built-in manual defaults run; a refused *new* file keeps the last good parameters and is not
        this: see ``stages.rejected``).
        """
        if self._stopping.is_set():
            return SHUTTING_DOWN
        if self.ended:
            return SOURCE_ENDED
        if not self._first_frame.is_set():
            return STARTING
        if not self.camera_ok:
            return CAMERA_LOST
        stage = self.stage
        if self.config.params_file is not None and (stage is None or stage.origin != str(self.config.params_file)):
            return PARAMS_UNUSABLE
        return MEASURING

    def _blind(self) -> str | None:
        """The service's condition when it is blind, for the send clock (None: the estimate decides)."""
        cond = self.condition
        return None if cond == MEASURING else cond

    def reload_params(self, path: Path | None = None) -> bool:
        """Re-read the parameter file (see :meth:`StageHolder.reload`). Never raises."""
        return self.stages.reload(path)

    # -- start-up --------------------------------------------------------------------------------
    def startup(self, stop: threading.Event) -> None:
        """Open the source, build the stages, start every thread, wait for the first frame.

        Raises UavDepthError (ConfigError, CalibrationError, SourceError, ...) when the
        daemon cannot start; everything started so far is stopped again.
        """
        cfg = self.config
        log.info("starting: %s", cfg.summary())
        try:
            self._open_stages()
            self._start_threads()
        except BaseException:
            self.shutdown()
            raise
        deadline = time.monotonic() + cfg.service.first_frame_timeout_s
        while not self._first_frame.is_set():
            if stop.is_set() or self.ended:
                return
            if self._startup_error is not None:
                err = self._startup_error
                self.shutdown()
                raise err
            if time.monotonic() > deadline:
                self.shutdown()
                raise SourceError(f"no frame processed within service.first_frame_timeout_s = "
                                  f"{cfg.service.first_frame_timeout_s:g} s ({self.capture.frames_in} frames captured "
                                  f"from {self.source.describe()})")
            self._first_frame.wait(0.05)
        self.state = "active"
        self.health.ready()

    def _open_stages(self) -> None:
        cfg = self.config
        self.source.open()      # SourceError when the camera is missing: fails fast, says what
        self.camera_ok = True
        log.info("source: %s", self.source.describe())
        self.rectifier = Rectifier(resolve_calibration(cfg.calibration, self.source.calibration, cfg.source_kind))
        self.calibration = self.rectifier.calibration
        self.roi = resolve_roi(cfg.ranging.roi, self.calibration.width, self.calibration.height)
        if hasattr(self.source, "truth_roi"):
            self.source.truth_roi = self.roi    # the synthetic truth is taken where we range
        stage = self.stages.open(self.calibration, self.roi)
        c = self.calibration
        lim = stage.ranger.limits
        # the range DISTANCE_SENSOR states (where readings are precise enough to send), which the
        # autopilot's RNGFND1_MIN/MAX are set against; the farthest the search could see beside it
        log.info("calibration: f %.1f px, B %.4f m, %dx%d%s; ROI %s; range %.2f..%.2f m (stated on the wire; "
                 "the search reaches %.2f m)", c.focal_px, c.baseline_m,
                 c.width, c.height, "" if self.rectifier.passthrough else " (rectified from raw)", list(self.roi),
                 lim.min_distance_m, lim.stated_max_m, lim.max_distance_m)
        log.info("parameters: %s, hash %s", stage.origin, stage.hash)
        if cfg.logging.dir is not None:
            ensure_log_dir(cfg.logging.dir)     # ConfigError: exit 78 before anything flies
            self.framelog = FrameLogger(cfg.logging, self.calibration, cfg.source_kind,
                                        on_stop=lambda why: self.link.statustext("uav-depth: logging stopped",
                                                                                 "warning")).start()

    def _start_threads(self) -> None:
        cfg = self.config
        self.link.start()
        self.clock = SendClock(self.link, cfg.mavlink, cfg.ranging.max_age_ms / 1000.0,
                               estimate=lambda: self.estimate, limits=self._limits,
                               state=lambda: self.state, blind=self._blind).start()
        if cfg.liveview.enabled:
            c = self.calibration
            self.liveview = LiveView.bind(cfg.liveview, c.focal_px * c.baseline_m, self._view_status)
        if cfg.rig_check.interval_s > 0:
            self.rigwatch = RigWatch(cfg.rig_check, lambda text: self.link.statustext(text, "warning"))
            self.rigwatch.start(self._stopping)
        if cfg.obstacle_distance.enabled:
            self.obstacles = self._obstacle_sender().start(self._stopping)
        for name, target in (("capture", self.capture.run), ("stereo", self._stereo_loop)):
            t = threading.Thread(target=target, name=name, daemon=True)
            self._threads[name] = t
            t.start()
        if cfg.params_file is not None:
            self._watcher = FileWatcher(cfg.params_file, self.reload_params, cfg.service.params_poll_s,
                                        since=self.stages.signature)
            self._watcher.start(self._stopping)
            log.info("watching %s for new parameters (%s)", cfg.params_file, "inotify + poll")

    def _obstacle_sender(self) -> ObstacleSender:
        c, clock, stype = self.calibration, self.clock, self.clock.sensor_type
        lim = lambda: limits_cm(self._limits().min_distance_m, self._limits().max_distance_m)  # noqa: E731
        return ObstacleSender(self.config.obstacle_distance, Field(c.width, c.focal_px, c.principal_point[0]),
                              c.focal_px * c.baseline_m, self.config.ranging.max_age_ms / 1000.0,
                              lambda: self.stage.params, lim,
                              lambda r: self.link.send_measurement("OBSTACLE_DISTANCE", encoder(r, stype),
                                                                   r.time_usec / 1e6 + clock.t_start,
                                                                   self.config.ranging.max_age_ms / 1000.0),
                              clock.t_start)

    def _view_status(self) -> dict[str, Any]:
        clock = self.clock
        return {"state": self.state, "fps": self.stats.fps(time.monotonic()), "camera_ok": self.camera_ok,
                "wire": clock.last_report if clock else None}

    def _limits(self) -> RangeLimits:
        stage = self.stage
        assert stage is not None
        return stage.ranger.limits

    # -- threads ---------------------------------------------------------------------------------
    def _camera_lost(self, why: str) -> None:
        if self.camera_ok:
            self.camera_ok = False
            self.state = "critical"
            self._gate.reset()
            log.error("camera lost: %s; reconnecting (no measurement is sent meanwhile)", why)
            self.link.statustext("uav-depth: camera lost", "error")

    def _camera_back(self) -> None:
        if not self.camera_ok:
            self.camera_ok = True
            self.state = "active" if self._first_frame.is_set() else "boot"
            log.info("camera back: %s", self.source.describe())
            self.link.statustext("uav-depth: camera back", "notice")

    def _source_ended(self, why: str) -> None:
        self.ended = why
        self.state = "standby"

    def _stereo_loop(self) -> None:
        while not self._stopping.is_set():
            frame = self._mailbox.get(0.2)
            if frame is None:
                continue
            try:
                self._process(frame)
            except FrameError as exc:
                if not self._first_frame.is_set():
                    self._startup_error = ConfigError("calibration", "must match the frames", str(exc))
                    return
                log.error("frame %d skipped: %s", frame.index, exc)
            except Exception:   # keep flying: one bad frame must not end the stereo loop
                log.exception("frame %d failed", frame.index)
            finally:
                self.health.busy_since = None
                self.frames_done += 1

    def _process(self, frame: Frame) -> None:
        stage = self.stage               # one read: a swap lands between frames, never inside one
        assert stage is not None and self.rectifier is not None
        t_start = time.monotonic()
        self.health.busy_since = t_start
        left, right = self.rectifier(frame.left, frame.right)
        t_rect = time.monotonic()
        result = stage.pipeline.run(left, right)
        t_disp = time.monotonic()
        m = self._gate.near(stage.ranger.measure(result), stage.ranger.limits.min_distance_m, frame.t_capture)
        t_done = time.monotonic()
        timings = {"queue": (t_start - frame.t_capture) * 1e3, "rectify": (t_rect - t_start) * 1e3,
                   "disparity": (t_disp - t_rect) * 1e3, "ranging": (t_done - t_disp) * 1e3,
                   "latency": (t_done - frame.t_capture) * 1e3}
        est = Estimate(m, stage.ranger.limits, frame.t_capture, t_done, frame.index, stage.hash, frame.truth_m,
                       timings, too_close=m.too_close)
        self.last_estimate = est
        if not m.valid:
            self.estimate = est        # nothing measured (the wire goes blind), or too close: never held back
        elif self._gate.accept(m.distance_m, frame.t_capture):
            self.estimate = est
        # else: a single-frame jump, held back; the previous estimate ages out on its own
        clock = self.clock
        if clock is not None:
            clock.notify()             # sent now, not at the next tick
        self.stats.add(t_done, timings)
        if self.liveview is not None:   # references only: nothing is drawn unless someone watches
            self.liveview.offer(left, result.disparity, est, self.roi, stage.params)
        if self.rigwatch is not None:
            self.rigwatch.offer(left, right)
        if self.obstacles is not None:
            self.obstacles.offer(left, right, frame.t_capture)
        if self.framelog is not None:
            self.framelog.consider(frame.index, left, right,
                                   frame_meta(frame, est, self.t0, self.config.source_kind, self.roi), frame.reference,
                                   frame.reference_source)
        self._first_frame.set()

    # -- main loop -------------------------------------------------------------------------------
    def healthy(self, now: float | None = None) -> bool:
        """True while every loop is alive and nothing is stuck (see :meth:`Health.healthy`)."""
        return self.health.healthy(self.clock, self._threads, now)

    def status_line(self) -> str:
        stage = self.stage
        return status_line(self.stats, self.last_estimate, self.clock, stage.hash if stage else None,
                           self.camera_ok)

    def _drain(self, stop: threading.Event) -> None:
        """A finite source ended: let the frames in flight finish (bounded), then say what was dropped."""
        deadline = time.monotonic() + self.config.service.stall_timeout_s
        mb, delivered = self._mailbox, self.capture.frames_in
        while self.frames_done + mb.dropped < delivered and time.monotonic() < deadline and not stop.wait(0.02):
            pass
        log.info("source delivered %d frames: %d processed, %d dropped (a newer frame replaced one not yet "
                 "processed%s)", delivered, self.frames_done, mb.dropped,
                 "" if getattr(self.source, "lossless", False) else "; source.lossless: true processes every frame")

    def run(self, stop: threading.Event) -> ShutdownReport:
        """Start, serve until ``stop`` is set (or a finite source ends), shut down. Raises on start-up failure."""
        self.startup(stop)
        try:
            while not stop.wait(0.1):
                if self.ended:
                    self._drain(stop)
                    break
                if self._reload_now.is_set():
                    self._reload_now.clear()
                    if self._watcher is not None:
                        self._watcher.poke()     # read on the watcher's thread: the loop never waits
                    else:
                        self.reload_params()
                self.health.tick(self.healthy)
        finally:
            report = self.shutdown()
        return report

    # -- shutdown --------------------------------------------------------------------------------
    def shutdown(self) -> ShutdownReport:
        """Stop everything within ``service.shutdown_timeout_s``; say what was abandoned."""
        t0 = time.monotonic()
        deadline = t0 + self.config.service.shutdown_timeout_s
        left = lambda: max(0.0, deadline - time.monotonic())  # noqa: E731
        self.notifier.stopping("stopping")
        self._stopping.set()
        abandoned: list[str] = []
        if self.clock is not None and self.clock.alive:
            self.link.statustext("uav-depth: stopping", "notice")
            if not self.clock.stop(left()):
                abandoned.append("the MAVLink send clock")
            self.state = "poweroff"
            self.link.heartbeat("poweroff")
        self.stages.close()     # a trial in progress ends now, not after its time bound
        for name, t in self._threads.items():
            t.join(left())
            if t.is_alive():
                abandoned.append(f"the {name} thread{self.health.abandoned_detail(name)}")
        if self._watcher is not None and not self._watcher.join(left()):
            abandoned.append("the parameter watcher")
        if self.obstacles is not None and not self.obstacles.join(left()):
            abandoned.append("the obstacle pass")
        if self.rigwatch is not None and not self.rigwatch.join(left()):
            abandoned.append("the rig check")
        if self.liveview is not None and not self.liveview.close(left()):
            abandoned.append("the live view server")
        if self.framelog is not None:
            lost = self.framelog.close(left())
            if lost:
                abandoned.append(f"{lost} queued frame(s) of the frame log")
        closer = threading.Thread(target=self._close_source, name="source-close", daemon=True)
        closer.start()
        closer.join(left())
        if closer.is_alive():
            abandoned.append("closing the source")
        if not self.link.close(left()):
            abandoned.append("the MAVLink I/O thread")
        took = time.monotonic() - t0
        if abandoned:
            log.warning("shutdown after %.2f s abandoned: %s", took, "; ".join(abandoned))
        else:
            log.info("shutdown complete in %.2f s", took)
        self.notifier.close()
        return ShutdownReport(took, tuple(abandoned))

    def _close_source(self) -> None:
        try:
            self.source.close()
        except Exception:   # shutting down: a failing close is reported, not raised
            log.warning("closing the source failed", exc_info=True)
