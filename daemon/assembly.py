"""Building a service from its config, apart from running it (uvicorn's ``Config.load()``).

:func:`assemble` builds what needs no camera: the frame source, the MAVLink link, sd_notify,
the shared :class:`~uav_depth.daemon.state.ServiceState`, health, the stage holder with its
trial child, the mailbox and the capture loop. :func:`fit` builds, once start-up has opened
the source and knows its calibration, what needs the camera: the rectifier and ranging ROI,
the send clock, the frame logger, the live view, the rig check, the OBSTACLE_DISTANCE pass
and the parameter watcher. :class:`~uav_depth.daemon.service.Service` only runs them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable

from uav_depth.core.errors import ConfigError
from uav_depth.core.rectify import Rectifier
from uav_depth.daemon.capture import Capture, Mailbox
from uav_depth.daemon.config import RunConfig
from uav_depth.daemon.framelog import FrameLogger, ensure_log_dir
from uav_depth.daemon.health import Health
from uav_depth.daemon.liveview import LiveView
from uav_depth.daemon.link.clock import SendClock
from uav_depth.daemon.link.endpoint import MavlinkLink
from uav_depth.daemon.notify import Notifier
from uav_depth.daemon.obstacles import Field, ObstacleReport, ObstacleSender, encoder, limits_cm
from uav_depth.core.ranging import resolve_roi
from uav_depth.daemon.reload import FileWatcher
from uav_depth.daemon.rigwatch import RigWatch
from uav_depth.daemon.sources import FrameSource, create_source
from uav_depth.daemon.stage import StageHolder, resolve_calibration
from uav_depth.daemon.state import ServiceState
from uav_depth.daemon.trial import Trials

log = logging.getLogger("uav_depth.service")


@dataclass
class Parts:
    """What one service is built from, before any camera is opened."""

    config: RunConfig
    source: FrameSource
    link: MavlinkLink
    notifier: Notifier
    state: ServiceState
    health: Health
    stages: StageHolder
    mailbox: Mailbox
    capture: Capture


@dataclass
class Fitted:
    """What start-up builds for the opened camera (optional parts are None when the config turns them off)."""

    rectifier: Rectifier
    roi: tuple[int, int, int, int]
    clock: SendClock
    framelog: FrameLogger | None = None
    liveview: LiveView | None = None
    rigwatch: RigWatch | None = None
    obstacles: ObstacleSender | None = None
    watcher: FileWatcher | None = None


def assemble(config: RunConfig, status: Callable[[], str], *, source: FrameSource | None = None,
             pose_provider: Callable[[float], Any] | None = None, link: MavlinkLink | None = None,
             notifier: Notifier | None = None) -> Parts:
    """Build the camera-independent parts; ``status`` builds the status line (the service's).

    ``source``: a ready-made (unopened) FrameSource instead of the config's;
    ``pose_provider``: handed to the synthetic source (SITL); ``link``: a MavlinkLink to use
    (else one is built from ``config.mavlink``); ``notifier``: sd_notify (default: from the
    environment). ConfigError when a pose provider is given for another source.
    """
    state = ServiceState()
    svc = config.service
    if source is None:
        kwargs: dict[str, Any] = {"stop_event": state.stopping}
        if pose_provider is not None:
            if config.source_kind != "synthetic":
                raise ConfigError("source.kind", "must be synthetic when a pose provider drives the rig",
                                  config.source_kind)
            kwargs["pose_provider"] = pose_provider
        source = create_source(config.source, **kwargs)
    link = link if link is not None else MavlinkLink(config.mavlink, svc.reconnect_min_s, svc.reconnect_max_s)
    notifier = notifier if notifier is not None else Notifier()
    mailbox = Mailbox()
    return Parts(config=config, source=source, link=link, notifier=notifier, state=state,
                 health=Health(svc, notifier, state, status),
                 stages=StageHolder(config.params_file, config.ranging, link.statustext, state.stopping,
                                    Trials(svc.trial_timeout_s)),
                 mailbox=mailbox, capture=Capture(source, svc, mailbox, state, link.statustext))


@dataclass(frozen=True)
class Hooks:
    """What the camera-dependent parts ask of the running service (its bound methods)."""

    blind: Callable[[], str | None]                # the service's condition when blind, else None
    heartbeat_state: Callable[[], str]             # HEARTBEAT system state
    view_status: Callable[[], dict[str, Any]]      # the live view's status panel


def rectify(parts: Parts) -> tuple[Rectifier, tuple[int, int, int, int]]:
    """The rectifier and the ranging ROI for the opened source (CalibrationError when there is none), once the
    log directory is known to be usable (ConfigError)."""
    cfg = parts.config
    if cfg.logging.dir is not None:
        ensure_log_dir(cfg.logging.dir)     # ConfigError: exit 78 before anything flies, as run --check checks it
    rectifier = Rectifier(resolve_calibration(cfg.calibration, parts.source.calibration, cfg.source_kind))
    c = rectifier.calibration
    roi = resolve_roi(cfg.ranging.roi, c.width, c.height)
    if hasattr(parts.source, "truth_roi"):
        parts.source.truth_roi = roi    # the synthetic truth is taken where we range
    return rectifier, roi


def fit(parts: Parts, rectifier: Rectifier, roi: tuple[int, int, int, int], hooks: Hooks) -> Fitted:
    """Build (unstarted, except the frame logger and the live view, which bind) the camera-dependent parts."""
    cfg, link, stages, c = parts.config, parts.link, parts.stages, rectifier.calibration
    fitted = Fitted(rectifier, roi, SendClock(link, cfg.mavlink, cfg.ranging.max_age_ms / 1000.0,
                                              estimate=parts.state.current_estimate, limits=stages.limits,
                                              state=hooks.heartbeat_state, blind=hooks.blind))
    announce = _Announce(link, cfg.ranging.max_age_ms / 1000.0, fitted.clock)
    if cfg.logging.dir is not None:
        fitted.framelog = FrameLogger(cfg.logging, c, cfg.source_kind, on_stop=announce.logging_stopped)
    if cfg.liveview.enabled:
        fitted.liveview = LiveView.bind(cfg.liveview, c.focal_px * c.baseline_m, hooks.view_status)
    if cfg.rig_check.interval_s > 0:
        fitted.rigwatch = RigWatch(cfg.rig_check, announce.warning)
    if cfg.obstacle_distance.enabled:
        fitted.obstacles = ObstacleSender(cfg.obstacle_distance, Field(c.width, c.focal_px, c.principal_point[0]),
                                          c.focal_px * c.baseline_m, cfg.ranging.max_age_ms / 1000.0,
                                          stages.params, announce.obstacle_limits_cm(stages),
                                          announce.obstacle_distance, fitted.clock.t_start)
    if cfg.params_file is not None:
        fitted.watcher = FileWatcher(cfg.params_file, stages.reload, cfg.service.params_poll_s,
                                     since=stages.signature)
    return fitted


class _Announce:
    """The link as the frame logger, the rig check and the OBSTACLE_DISTANCE pass use it."""

    def __init__(self, link: MavlinkLink, max_age_s: float, clock: SendClock):
        self.link, self.max_age_s, self.clock = link, max_age_s, clock

    def logging_stopped(self, why: str) -> None:
        self.link.statustext("uav-depth: logging stopped", "warning")

    def warning(self, text: str) -> None:
        self.link.statustext(text, "warning")

    def obstacle_distance(self, report: ObstacleReport) -> None:
        self.link.send_measurement("OBSTACLE_DISTANCE", encoder(report, self.clock.sensor_type),
                                   report.time_usec / 1e6 + self.clock.t_start, self.max_age_s)

    @staticmethod
    def obstacle_limits_cm(stages: StageHolder) -> Callable[[], tuple[int, int]]:
        def limits() -> tuple[int, int]:
            lim = stages.limits()
            return limits_cm(lim.min_distance_m, lim.max_distance_m)
        return limits
