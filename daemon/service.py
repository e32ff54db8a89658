"""The daemon: one Service that runs start-up, the main loop and shutdown; nothing else.

Construction is apart (:mod:`uav_depth.daemon.assembly`: every collaborator built once
from the config); what the threads share lives in one
:class:`~uav_depth.daemon.state.ServiceState`, each field written by one thread.
Threads and who waits on whom (nobody waits on the stereo stage):

- ``capture`` (:mod:`uav_depth.daemon.capture`): reads the source into a one-slot
  mailbox (the newest frame wins). Camera loss: close, reopen with back-off,
  STATUSTEXT "camera lost" / "camera back".
- ``stereo``: takes the newest frame, rectifies, runs the disparity pipeline and
  ranging of the current :class:`~uav_depth.daemon.stage.Stage` (one attribute read
  per frame, so a parameter swap never interrupts a frame), and publishes an
  :class:`~uav_depth.daemon.estimate.Estimate` by one assignment. It owns the outlier gate.
- ``mavlink-clock`` (:class:`~uav_depth.daemon.link.clock.SendClock`): DISTANCE_SENSOR
  as estimates appear, HEARTBEAT at 1 Hz, nothing while :attr:`Service.condition` is blind.
- ``mavlink-io``: the link's reader and writer; ``params-watch``: hot reload (each new
  file first run in a child process, :mod:`uav_depth.daemon.trial`); ``frame-logger``,
  ``obstacles``, ``rig-check``, ``liveview`` where configured.
- the caller's thread runs :meth:`Service.run`: start-up, then health checks (every
  thread above is watched: one dead stops WATCHDOG=1), sd_notify and the status line
  (:mod:`uav_depth.daemon.health`) until the stop event is set, then a bounded shutdown
  that sends nothing after it began and says what it abandoned.

Signal handlers (in the CLI) only set events: ``stop``, :meth:`Service.request_log_frame`,
:meth:`Service.request_reload`.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import SourceError
from uav_depth.daemon.assembly import Fitted, Hooks, Parts, assemble, fit, rectify
from uav_depth.daemon.config import RunConfig
from uav_depth.daemon.health import status_line
from uav_depth.daemon.link.conditions import Condition
from uav_depth.daemon.link.endpoint import MavlinkLink
from uav_depth.daemon.notify import Notifier
from uav_depth.daemon.sources import FrameSource
from uav_depth.daemon.stage import Stage
from uav_depth.daemon.stereo import StereoLoop

log = logging.getLogger("uav_depth.service")

#: HEARTBEAT system state per blind condition (measuring: active).
_HEARTBEAT = {Condition.SHUTTING_DOWN: "poweroff", Condition.SOURCE_ENDED: "standby", Condition.STARTING: "boot",
              Condition.CAMERA_LOST: "critical", Condition.PARAMS_UNUSABLE: "critical"}


@dataclass(frozen=True)
class ShutdownReport:
    duration_s: float
    abandoned: tuple[str, ...] = ()

    @property
    def clean(self) -> bool:
        return not self.abandoned


class Service:
    """The daemon, usable in-process: ``Service(config).run(stop_event)``.

    The keyword arguments go to :func:`~uav_depth.daemon.assembly.assemble` (a
    ready-made source, a pose provider, a link, a notifier); ``service.link`` exists
    before ``run``, so callers can subscribe.
    """

    def __init__(self, config: RunConfig, *, source: FrameSource | None = None,
                 pose_provider: Callable[[float], Any] | None = None, link: MavlinkLink | None = None,
                 notifier: Notifier | None = None):
        self.parts: Parts = assemble(config, self.status_line, source=source, pose_provider=pose_provider,
                                     link=link, notifier=notifier)
        self.config = config
        self.state = self.parts.state
        self.fitted: Fitted | None = None
        self.t0 = time.monotonic()
        self._stereo: StereoLoop | None = None
        self._reload_now = threading.Event()

    # -- control from signal handlers (they only set events) -------------------------------------
    def request_log_frame(self) -> None:
        """Log the next processed frame (SIGUSR1)."""
        if self.framelog is not None:
            self.framelog.request()

    def request_reload(self) -> None:
        """Re-read the parameter file now (SIGHUP)."""
        self._reload_now.set()

    # -- what the other parts read -------------------------------------------------------------
    source = property(lambda self: self.parts.source)
    link = property(lambda self: self.parts.link)
    notifier = property(lambda self: self.parts.notifier)
    health = property(lambda self: self.parts.health)
    stages = property(lambda self: self.parts.stages)
    mailbox = property(lambda self: self.parts.mailbox)
    stats = property(lambda self: self.state.stats)
    last_estimate = property(lambda self: self.state.last_estimate)
    ended = property(lambda self: self.state.ended)
    frames_done = property(lambda self: self.state.frames_done)
    clock = property(lambda self: self.fitted.clock if self.fitted else None)
    framelog = property(lambda self: self.fitted.framelog if self.fitted else None)
    liveview = property(lambda self: self.fitted.liveview if self.fitted else None)

    @property
    def stage(self) -> Stage | None:
        """The current stereo stage (pipeline + ranger); replaced as a whole on reload."""
        return self.stages.stage

    @property
    def calibration(self) -> Calibration | None:
        return self.fitted.rectifier.calibration if self.fitted else None

    @property
    def condition(self) -> Condition:
        """The one condition that decides what goes on the wire (:mod:`uav_depth.daemon.link.contract`).

        ``MEASURING``: frames flow through a stage built from the configured parameters, and each
        estimate then says whether it measured and how old it is (the wire contract decides per
        estimate). Every other value is blind, whatever the newest estimate says:
        ``SHUTTING_DOWN`` once shutdown began; ``SOURCE_ENDED`` when a finite source ended;
        ``STARTING`` before the first frame; ``CAMERA_LOST`` while the source is reconnecting;
        ``PARAMS_UNUSABLE`` when the configured parameter file is not what flies (missing, so the
        built-in manual defaults run; a refused *new* file keeps the last good parameters and is not
        this: see ``stages.rejected``).
        """
        st = self.state
        if st.stopping.is_set():
            return Condition.SHUTTING_DOWN
        if st.ended:
            return Condition.SOURCE_ENDED
        if not st.first_frame.is_set():
            return Condition.STARTING
        if not st.camera_ok:
            return Condition.CAMERA_LOST
        stage = self.stage
        if self.config.params_file is not None and (stage is None or stage.origin != str(self.config.params_file)):
            return Condition.PARAMS_UNUSABLE
        return Condition.MEASURING

    def blind(self) -> Condition | None:
        """The service's condition when it is blind, for the send clock (None: the estimate decides)."""
        cond = self.condition
        return None if cond == Condition.MEASURING else cond

    def heartbeat_state(self) -> str:
        """HEARTBEAT's system state, from the one condition."""
        return _HEARTBEAT.get(self.condition, "active")

    def reload_params(self) -> bool:
        """Re-read the parameter file (see :meth:`StageHolder.reload`). Never raises."""
        return self.stages.reload()

    def healthy(self, now: float | None = None) -> bool:
        """True while every thread lives and nothing is stuck (see :meth:`Health.healthy`)."""
        return self.health.healthy(now)

    def status_line(self) -> str:
        stage, health = self.stage, self.parts.health
        notes = tuple(f"THREAD {name} DEAD" for name in health.dead) + tuple(getattr(self.source, "notes", ()))
        return status_line(self.stats, self.last_estimate, self.clock, stage.hash if stage else None,
                           self.state.camera_ok, notes=notes)

    # -- start-up --------------------------------------------------------------------------------
    def startup(self, stop: threading.Event) -> None:
        """Open the source, build the stages, start every thread, wait for the first frame.

        Raises UavDepthError (ConfigError, CalibrationError, SourceError, ...) when the
        daemon cannot start; everything started so far is stopped again.
        """
        cfg, st = self.config, self.state
        log.info("starting: %s", cfg.summary())
        try:
            self._open()
            self._start_threads()
        except BaseException:
            self.shutdown()
            raise
        deadline = time.monotonic() + cfg.service.first_frame_timeout_s
        while not st.first_frame.is_set():
            if stop.is_set() or st.ended:
                return
            if st.startup_error is not None:
                self.shutdown()
                raise st.startup_error
            if time.monotonic() > deadline:
                self.shutdown()
                raise SourceError(f"no frame processed within service.first_frame_timeout_s = "
                                  f"{cfg.service.first_frame_timeout_s:g} s ({self.parts.capture.frames_in} frames "
                                  f"captured from {self.source.describe()})")
            st.first_frame.wait(0.05)
        self.health.ready()

    def _open(self) -> None:
        self.source.open()      # SourceError when the camera is missing: fails fast, says what
        log.info("source: %s", self.source.describe())
        rectifier, roi = rectify(self.parts)
        stage = self.stages.open(rectifier.calibration, roi)
        c, lim = rectifier.calibration, stage.ranger.limits
        # the range DISTANCE_SENSOR states (where readings are precise enough to send), which the
        # autopilot's RNGFND1_MIN/MAX are set against; the farthest the search could see beside it
        log.info("calibration: f %.1f px, B %.4f m, %dx%d%s; ROI %s; range %.2f..%.2f m (stated on the wire; "
                 "the search reaches %.2f m)", c.focal_px, c.baseline_m, c.width, c.height,
                 "" if rectifier.passthrough else " (rectified from raw)", list(roi), lim.min_distance_m,
                 lim.stated_max_m, lim.max_distance_m)
        log.info("parameters: %s, hash %s", stage.origin, stage.hash)
        self.fitted = fit(self.parts, rectifier, roi, Hooks(self.blind, self.heartbeat_state, self._view_status))

    def _start_threads(self) -> None:
        f, health, stopping = self.fitted, self.health, self.state.stopping
        assert f is not None
        started: list[tuple[str, Any]] = [("mavlink-io", self.link.start()), ("mavlink-clock", f.clock.start())]
        if f.framelog is not None:
            started.append(("frame-logger", f.framelog.start()))
        if f.liveview is not None:
            started.append(("liveview", f.liveview))          # serving since it bound its port
        for name, worker in (("rig-check", f.rigwatch), ("obstacles", f.obstacles)):
            if worker is not None:
                started.append((name, worker.start(stopping)))
        self._stereo = StereoLoop(self.config, self.state, self.mailbox, self.stages, f, self.t0)
        started += [("capture", self.parts.capture.start()), ("stereo", self._stereo.start())]
        if f.watcher is not None:
            started.append(("params-watch", f.watcher.start(stopping)))
            log.info("watching %s for new parameters (%s)", self.config.params_file, "inotify + poll")
        for name, part in started:
            health.watch(name, part)

    def _view_status(self) -> dict[str, Any]:
        clock = self.clock
        return {"state": self.heartbeat_state(), "fps": self.stats.fps(time.monotonic()),
                "camera_ok": self.state.camera_ok, "wire": clock.last_report if clock else None}

    # -- main loop -------------------------------------------------------------------------------
    def _drain(self, stop: threading.Event) -> None:
        """A finite source ended: let the frames in flight finish (bounded), then say what was dropped."""
        deadline = time.monotonic() + self.config.service.stall_timeout_s
        mb, st, delivered = self.mailbox, self.state, self.parts.capture.frames_in
        while st.frames_done + mb.dropped < delivered and time.monotonic() < deadline and not stop.wait(0.02):
            pass
        log.info("source delivered %d frames: %d processed, %d dropped (a newer frame replaced one not yet "
                 "processed%s)", delivered, st.frames_done, mb.dropped,
                 "" if getattr(self.source, "lossless", False) else "; source.lossless: true processes every frame")

    def run(self, stop: threading.Event) -> ShutdownReport:
        """Start, serve until ``stop`` is set (or a finite source ends), shut down. Raises on start-up failure."""
        self.startup(stop)
        try:
            while not stop.wait(0.1):
                if self.state.ended:
                    self._drain(stop)
                    break
                if self._reload_now.is_set():
                    self._reload_now.clear()
                    watcher = self.fitted.watcher if self.fitted else None
                    if watcher is not None:
                        watcher.poke()     # read on the watcher's thread: the loop never waits
                self.health.tick()
        finally:
            report = self.shutdown()
        return report

    # -- shutdown --------------------------------------------------------------------------------
    def shutdown(self) -> ShutdownReport:
        """Stop everything within ``service.shutdown_timeout_s``; say what was abandoned.

        Nothing is sent once it begins: the condition turns blind, the send clock and the
        OBSTACLE_DISTANCE pass are stopped, and only then do "stopping" and the poweroff
        HEARTBEAT go out (the link writes in order, so they are the last words).
        """
        t0 = time.monotonic()
        deadline = t0 + self.config.service.shutdown_timeout_s
        left = lambda: max(0.0, deadline - time.monotonic())  # noqa: E731
        self.notifier.stopping("stopping")
        self.state.stopping.set()
        self.stages.close()     # a trial in progress ends now, not after its time bound
        f = self.fitted
        abandoned = _stop_senders(f, left) if f is not None else []
        if f is not None:
            self.link.statustext("uav-depth: stopping", "notice")
            self.link.heartbeat("poweroff")
        for name, loop in (("capture", self.parts.capture), ("stereo", self._stereo)):
            if loop is not None and not loop.join(left()):
                abandoned.append(f"the {name} thread{self.health.abandoned_detail(name)}")
        if f is not None:
            abandoned += _stop_rest(f, left)
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


def _stop_senders(f: Fitted, left: Callable[[], float]) -> list[str]:
    """Stop what queues measurements (the send clock, the obstacle pass); what did not stop in time."""
    abandoned = []
    if f.clock.alive and not f.clock.stop(left()):
        abandoned.append("the MAVLink send clock")
    if f.obstacles is not None and not f.obstacles.join(left()):
        abandoned.append("the obstacle pass")
    return abandoned


def _stop_rest(f: Fitted, left: Callable[[], float]) -> list[str]:
    """Stop the watcher, the rig check, the live view and the frame log; what did not stop in time."""
    abandoned = []
    if f.watcher is not None and not f.watcher.join(left()):
        abandoned.append("the parameter watcher")
    if f.rigwatch is not None and not f.rigwatch.join(left()):
        abandoned.append("the rig check")
    if f.liveview is not None and not f.liveview.close(left()):
        abandoned.append("the live view server")
    if f.framelog is not None:
        lost = f.framelog.close(left())
        if lost:
            abandoned.append(f"{lost} queued frame(s) of the frame log")
    return abandoned
