"""The daemon: one Service with start-up, main loop and shutdown.

Threads and who waits on whom (nobody waits on the stereo stage):

- ``capture``: reads the source into a one-slot mailbox (the newest frame wins;
  older ones are dropped, never queued). Camera loss: close, reopen with
  back-off, STATUSTEXT "camera lost" / "camera back".
- ``stereo``: takes the newest frame, rectifies, runs the disparity pipeline and
  ranging, and publishes an :class:`~uav_depth.daemon.ranging.Estimate` by one
  assignment. It reads the current stage (pipeline + ranger) by one attribute
  read per frame, so a parameter swap never interrupts a frame.
- ``mavlink-clock`` (:class:`~uav_depth.daemon.mavlink_out.SendClock`): DISTANCE_SENSOR
  at ``rate_hz``, HEARTBEAT at 1 Hz, from the newest estimate if it is fresh.
- ``mavlink-io``: the link's reader and reconnector; ``params-watch``: hot
  reload; ``frame-logger``: the background writer.
- the caller's thread runs :meth:`Service.run`: start-up, then health checks,
  sd_notify WATCHDOG/STATUS and the status log line until the stop event is set,
  then a bounded shutdown that says what it abandoned.

Signal handlers (in the CLI) only set events: ``stop``, :meth:`Service.request_log_frame`,
:meth:`Service.request_reload`.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from uav_depth.core.calibration import Calibration
from uav_depth.daemon.config import RunConfig
from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError, FrameError, SourceError, UavDepthError
from uav_depth.daemon.framelog import FrameLogger
from uav_depth.daemon.liveview import LiveView
from uav_depth.daemon.mavlink_out import MavlinkLink, SendClock
from uav_depth.daemon.notify import Notifier
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams, load_params
from uav_depth.daemon.ranging import Estimate, OutlierGate, Ranger, RangeLimits, resolve_roi
from uav_depth.core.rectify import Rectifier
from uav_depth.daemon.reload import FileWatcher, file_signature
from uav_depth.daemon.sources import EndOfStream, Frame, FrameSource, create_source

log = logging.getLogger("uav_depth.service")


@dataclass(frozen=True)
class Stage:
    """What one parameter set builds: the pipeline and the ranger. Swapped as a whole."""

    params: StereoParams
    pipeline: DisparityPipeline
    ranger: Ranger
    origin: str

    @functools.cached_property
    def hash(self) -> str:   # computed once: every frame's estimate carries it
        return self.params.hash()


@dataclass(frozen=True)
class ShutdownReport:
    duration_s: float
    abandoned: tuple[str, ...] = ()

    @property
    def clean(self) -> bool:
        return not self.abandoned


class _Mailbox:
    """One slot: ``put`` replaces what is there (counting the drop), ``get`` waits for something new."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Frame | None = None
        self.dropped = 0

    def put(self, item: Frame) -> None:
        with self._cond:
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self._cond.notify()

    def get(self, timeout_s: float) -> Frame | None:
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            return item


@dataclass
class _Stats:
    """Rolling per-stage timings (ms) and counters for the status line and the benchmark."""

    window: int = 200
    stages: dict[str, collections.deque] = field(default_factory=dict)
    frames: int = 0
    frame_times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=200))

    def add(self, t_done: float, timings: dict[str, float]) -> None:
        self.frames += 1
        self.frame_times.append(t_done)
        for k, v in timings.items():
            self.stages.setdefault(k, collections.deque(maxlen=self.window)).append(v)

    def fps(self, now: float, span_s: float = 5.0) -> float:
        recent = [t for t in self.frame_times if now - t <= span_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)

    def median(self, stage: str) -> float:
        vals = sorted(self.stages.get(stage, ()))
        return vals[len(vals) // 2] if vals else math.nan


def compute_roi_px(params: StereoParams, width: int, height: int) -> tuple[int, int, int, int] | None:
    """The matching region ``compute.roi`` in px (None when it is the whole image).

    Outside it the pipeline leaves disparity NaN; ranging outside it finds nothing.
    """
    return None if params.compute.whole_frame else params.compute.roi_pixels(width, height)


def check_roi_against_compute(roi: tuple[int, int, int, int], params: StereoParams, width: int,
                              height: int) -> str | None:
    """A warning when the ranging ROI reaches outside the parameters' matching ROI, else None."""
    c = compute_roi_px(params, width, height)
    if c is None:
        return None
    x0, y0, x1, y1 = roi
    if x0 >= c[0] and y0 >= c[1] and x1 <= c[2] and y1 <= c[3]:
        return None
    return (f"ranging.roi {list(roi)} reaches outside the parameters' matching region compute.roi "
            f"(= {list(c)} px at {width}x{height}); disparity there is NaN, so ranging sees only the overlap")


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
        self.stats = _Stats()
        self.estimate: Estimate | None = None       # what the send clock reads; replaced by one assignment
        self.last_estimate: Estimate | None = None   # newest frame's result, accepted or not
        self.stage: Stage | None = None
        self.calibration: Calibration | None = None
        self.rectifier: Rectifier | None = None
        self.roi: tuple[int, int, int, int] | None = None
        self.clock: SendClock | None = None
        self.framelog: FrameLogger | None = None
        self.liveview: LiveView | None = None       # liveview.enabled: the read-only web page
        self.state = "boot"
        self.camera_ok = False
        self.ended: str | None = None
        self.t0 = time.monotonic()
        self._mailbox = _Mailbox()
        self._gate = OutlierGate(config.ranging.max_jump_rel, config.ranging.confirm_frames,
                                 forget_s=max(1.0, 2 * config.ranging.max_age_ms / 1000.0))
        self._threads: dict[str, threading.Thread] = {}
        self._first_frame = threading.Event()
        self._startup_error: UavDepthError | None = None
        self._busy_since: float | None = None      # when the stereo stage took its current frame
        self._source_since: float | None = None    # when the capture thread entered the source (read/open)
        self._reload_lock = threading.Lock()
        self._reload_now = threading.Event()
        self._watcher: FileWatcher | None = None
        self._params_signature: tuple[int, int, int] | None = None
        self._frames_in = 0

    # -- control from signal handlers (they only set events) -------------------------------------
    def request_log_frame(self) -> None:
        """Log the next processed frame (SIGUSR1)."""
        if self.framelog is not None:
            self.framelog.request()

    def request_reload(self) -> None:
        """Re-read the parameter file now (SIGHUP)."""
        self._reload_now.set()

    # -- stages ----------------------------------------------------------------------------------
    def _load_params(self) -> tuple[StereoParams, str]:
        path = self.config.params_file
        if path is None:
            return DEFAULT_PARAMS, "built-in manual defaults"
        self._params_signature = file_signature(Path(path))   # what the watcher compares against
        if not Path(path).exists():
            log.warning("parameter file %s does not exist: using the built-in manual defaults until it appears",
                        path)
            return DEFAULT_PARAMS, "built-in manual defaults"
        return load_params(path), str(path)

    def _build_stage(self, params: StereoParams, origin: str) -> Stage:
        assert self.calibration is not None and self.roi is not None
        ranger = Ranger(self.config.ranging, self.calibration, self.roi, params)
        warning = check_roi_against_compute(self.roi, params, self.calibration.width, self.calibration.height)
        if warning:
            log.warning("%s", warning)
        return Stage(params, DisparityPipeline(params), ranger, origin)

    def reload_params(self, path: Path | None = None) -> bool:
        """Re-read the parameter file; swap the stage if it is valid and new. Never raises.

        Invalid file: the last good parameters stay, one log line names the problem,
        a STATUSTEXT says so. Returns True when a new stage was swapped in.
        """
        path = Path(path or self.config.params_file) if (path or self.config.params_file) else None
        if path is None or self.stage is None:
            return False
        with self._reload_lock:
            current = self.stage
            if not path.exists():
                log.warning("parameter file %s removed; keeping parameters %s", path, current.hash)
                return False
            try:
                params = load_params(path)
                if params == current.params:
                    log.info("parameter file %s rewritten with the same parameters (hash %s)", path, current.hash)
                    return False
                stage = self._build_stage(params, str(path))
            except (ConfigError, FileFormatError, CalibrationError) as exc:
                log.error("parameters rejected, keeping %s: %s", current.hash, exc)
                self.link.statustext(f"uav-depth: params rejected, kept {current.hash[:8]}", "warning")
                return False
            self.stage = stage      # the swap: the stereo thread picks it up at its next frame
            log.info("parameters reloaded from %s: hash %s (was %s)", path, stage.hash, current.hash)
            self.link.statustext(f"uav-depth: params {stage.hash[:8]} loaded", "info")
            return True

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
                                  f"{cfg.service.first_frame_timeout_s:g} s ({self._frames_in} frames captured "
                                  f"from {self.source.describe()})")
            self._first_frame.wait(0.05)
        self.state = "active"
        status = self.status_line()
        log.info("ready: %s", status)
        self.notifier.ready(status)

    def _open_stages(self) -> None:
        cfg = self.config
        self.source.open()      # SourceError when the camera is missing: fails fast, says what
        self.camera_ok = True
        log.info("source: %s", self.source.describe())
        calib = cfg.calibration or self.source.calibration
        if calib is None:
            raise CalibrationError(f"source {cfg.source_kind} carries no calibration: set calibration: FILE "
                                   "(focal_px, baseline_m, width, height; K, D, R, T for raw frames)")
        if cfg.calibration is not None and self.source.calibration is not None \
                and cfg.calibration != self.source.calibration:
            log.warning("the config's calibration overrides the one the %s source carries", cfg.source_kind)
        self.rectifier = Rectifier(calib)
        self.calibration = self.rectifier.calibration
        self.roi = resolve_roi(cfg.ranging.roi, self.calibration.width, self.calibration.height)
        if hasattr(self.source, "truth_roi"):
            self.source.truth_roi = self.roi    # the synthetic truth is taken where we range
        params, origin = self._load_params()
        self.stage = self._build_stage(params, origin)
        c = self.calibration
        lim = self.stage.ranger.limits
        log.info("calibration: f %.1f px, B %.4f m, %dx%d%s; ROI %s; range %.2f..%.2f m", c.focal_px, c.baseline_m,
                 c.width, c.height, "" if self.rectifier.passthrough else " (rectified from raw)", list(self.roi),
                 lim.min_distance_m, lim.max_distance_m)
        log.info("parameters: %s, hash %s", origin, self.stage.hash)
        if cfg.logging.dir is not None:
            self.framelog = FrameLogger(cfg.logging, self.calibration, cfg.source_kind,
                                        on_stop=lambda why: self.link.statustext("uav-depth: logging stopped",
                                                                                 "warning")).start()

    def _start_threads(self) -> None:
        cfg = self.config
        self.link.start()
        self.clock = SendClock(self.link, cfg.mavlink, cfg.ranging.max_age_ms / 1000.0,
                               estimate=lambda: self.estimate, limits=self._limits,
                               state=lambda: self.state).start()
        if cfg.liveview.enabled:
            c = self.calibration
            self.liveview = LiveView.bind(cfg.liveview, c.focal_px * c.baseline_m, self._view_status)
        for name, target in (("capture", self._capture_loop), ("stereo", self._stereo_loop)):
            t = threading.Thread(target=target, name=name, daemon=True)
            self._threads[name] = t
            t.start()
        if cfg.params_file is not None:
            self._watcher = FileWatcher(cfg.params_file, self.reload_params, cfg.service.params_poll_s,
                                        since=self._params_signature)
            self._watcher.start(self._stopping)
            log.info("watching %s for new parameters (%s)", cfg.params_file, "inotify + poll")

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

    def _reconnect(self) -> None:
        svc = self.config.service
        delay = svc.reconnect_min_s
        try:
            self.source.close()
        except Exception:   # a vanished device may fail to close; we reopen anyway
            log.debug("source close failed", exc_info=True)
        while not self._stopping.is_set():
            if self._stopping.wait(delay):
                return
            try:
                with self._in_source():
                    self.source.open()
                return
            except SourceError as exc:
                log.info("camera still missing (%s); next try in %.1f s", exc, min(delay * 2, svc.reconnect_max_s))
            except Exception as exc:   # a driver error while reopening is the same story
                log.info("camera reopen failed (%s: %s)", type(exc).__name__, exc)
            delay = min(delay * 2, svc.reconnect_max_s)

    def _capture_loop(self) -> None:
        svc = self.config.service
        last = time.monotonic()
        while not self._stopping.is_set():
            try:
                with self._in_source():
                    frame = self.source.read(min(0.2, svc.frame_timeout_s))
            except EndOfStream as exc:
                log.info("%s", exc)
                self.ended = str(exc)
                self.state = "standby"
                return
            except SourceError as exc:
                self._camera_lost(str(exc))
                self._reconnect()
                last = time.monotonic()
                continue
            except Exception as exc:   # an unexpected driver error is a lost camera too
                log.exception("source read failed")
                self._camera_lost(f"{type(exc).__name__}: {exc}")
                self._reconnect()
                last = time.monotonic()
                continue
            now = time.monotonic()
            if frame is None:
                if now - last > svc.frame_timeout_s:
                    self._camera_lost(f"no frame for {now - last:.1f} s")
                    self._reconnect()
                    last = time.monotonic()
                continue
            last = now
            self._frames_in += 1
            self._camera_back()
            self._mailbox.put(frame)

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
                self._busy_since = None

    def _process(self, frame: Frame) -> None:
        stage = self.stage               # one read: a swap lands between frames, never inside one
        assert stage is not None and self.rectifier is not None
        t_start = time.monotonic()
        self._busy_since = t_start
        left, right = self.rectifier(frame.left, frame.right)
        t_rect = time.monotonic()
        result = stage.pipeline.run(left, right)
        t_disp = time.monotonic()
        m = stage.ranger.measure(result)
        t_done = time.monotonic()
        timings = {"queue": (t_start - frame.t_capture) * 1e3, "rectify": (t_rect - t_start) * 1e3,
                   "disparity": (t_disp - t_rect) * 1e3, "ranging": (t_done - t_disp) * 1e3,
                   "latency": (t_done - frame.t_capture) * 1e3}
        est = Estimate(m, stage.ranger.limits, frame.t_capture, t_done, frame.index, stage.hash, frame.truth_m,
                       timings)
        self.last_estimate = est
        if not m.valid:
            self.estimate = est        # the newest frame measured nothing: say so at the next tick
        elif self._gate.accept(m.distance_m, frame.t_capture):
            self.estimate = est
        # else: a single-frame jump, held back; the previous estimate ages out on its own
        self.stats.add(t_done, timings)
        if self.liveview is not None:   # references only: nothing is drawn unless someone watches
            self.liveview.offer(left, result.disparity, est, self.roi, stage.params)
        if self.framelog is not None:
            self.framelog.consider(frame.index, left, right, self._frame_meta(frame, est), frame.reference,
                                   frame.reference_source)
        self._first_frame.set()

    def _frame_meta(self, frame: Frame, est: Estimate) -> dict[str, Any]:
        m = est.measurement
        meta: dict[str, Any] = {
            "time_s": round(frame.t_capture - self.t0, 6),
            "wall_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "index": frame.index, "source": self.config.source_kind, "params_hash": est.params_hash,
            "roi": list(self.roi or ()), "measured_distance_m": m.distance_m, "sigma_m": m.sigma_m,
            "quality": m.quality, "bbox": list(m.bbox) if m.bbox else None, "reason": m.reason,
            "timings_ms": {k: round(v, 2) for k, v in est.timings_ms.items()},
        }
        if frame.truth_m is not None:
            meta["branch_distance_m"] = frame.truth_m
        meta.update({k: v for k, v in frame.meta.items() if k not in meta})
        return meta

    @contextlib.contextmanager
    def _in_source(self):
        """Mark the capture thread as inside the source (a read or open) for the stall check."""
        self._source_since = time.monotonic()
        try:
            yield
        finally:
            self._source_since = None

    # -- main loop -------------------------------------------------------------------------------
    def healthy(self, now: float | None = None) -> bool:
        """True while every loop is alive and neither the stereo stage nor the source is stuck.

        Stuck: one frame in the stereo stage, or one read/open of the source, for longer
        than ``service.stall_timeout_s``. Then WATCHDOG=1 stops and systemd restarts us.
        """
        now = time.monotonic() if now is None else now
        limit = self.config.service.stall_timeout_s
        busy, reading = self._busy_since, self._source_since
        return (self.clock is not None and self.clock.alive
                and all(t.is_alive() for t in self._threads.values())
                and (busy is None or now - busy < limit)
                and (reading is None or now - reading < limit))

    def status_line(self) -> str:
        now = time.monotonic()
        est = self.last_estimate
        if est is None:
            dist = "no frame yet"
        elif est.measurement.valid:
            truth = f", truth {est.truth_m:.3f} m" if est.truth_m is not None else ""
            dist = f"distance {est.measurement.distance_m:.3f} m (q {est.measurement.quality}{truth})"
        else:
            dist = f"no measurement ({est.measurement.reason})"
        clock = self.clock
        sent = f"{clock.valid_sent}/{clock.ticks} valid" if clock else "0/0"
        stage = self.stage
        return (f"{self.stats.fps(now):.1f} fps, {dist}, disparity {self.stats.median('disparity'):.0f} ms, "
                f"latency {self.stats.median('latency'):.0f} ms, sent {sent}, "
                f"params {stage.hash if stage else '-'}{'' if self.camera_ok else ', CAMERA LOST'}")

    def run(self, stop: threading.Event) -> ShutdownReport:
        """Start, serve until ``stop`` is set (or a finite source ends), shut down. Raises on start-up failure."""
        self.startup(stop)
        try:
            svc = self.config.service
            next_status = time.monotonic() + svc.status_interval_s
            next_dog = 0.0
            while not stop.wait(0.1):
                now = time.monotonic()
                if self.ended:
                    break
                if self._reload_now.is_set():
                    self._reload_now.clear()
                    self.reload_params()
                wd = self.notifier.watchdog_s
                if wd and now >= next_dog and self.healthy(now):
                    self.notifier.watchdog()
                    next_dog = now + wd / 3.0
                if now >= next_status:
                    line = self.status_line()
                    log.info("status: %s", line)
                    self.notifier.status(line)
                    next_status = now + svc.status_interval_s
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
        for name, t in self._threads.items():
            t.join(left())
            if t.is_alive():
                busy, reading = self._busy_since, self._source_since
                what = ""
                if name == "stereo" and busy:
                    what = f" (busy for {time.monotonic() - busy:.1f} s on a frame)"
                elif name == "capture" and reading:
                    what = f" (stuck for {time.monotonic() - reading:.1f} s in the source)"
                abandoned.append(f"the {name} thread{what}")
        if self._watcher is not None and not self._watcher.join(left()):
            abandoned.append("the parameter watcher")
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
