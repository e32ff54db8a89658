"""OBSTACLE_DISTANCE: 72 sectors across the camera's horizontal field, beside DISTANCE_SENSOR.

DISTANCE_SENSOR tells the autopilot about the branch ahead; ArduPilot's proximity
and avoidance (PRXn_TYPE=2) and PX4's Collision Prevention want everything in
front. With ``obstacle_distance.enabled`` a cheap full-width pass (the flying
parameters, over the whole frame, at ``obstacle_distance.scale`` of the resolution,
without WLS) runs on a niced thread of its own at up to ``rate_hz`` on the newest
rectified pair, and each pass becomes one message (docs/obstacles.md):

- the field [angle of column 0, angle of column W] (from the rectified principal
  point and focal length) is cut into 72 equal sectors: ``increment_f`` = field/72
  degrees, ``increment`` its rounded copy, ``angle_offset`` = the centre of element 0
  (what ArduPilot's ``handle_obstacle_distance_msg`` and PX4's ObstacleMath take it
  to be), ``frame`` MAV_FRAME_BODY_FRD (PX4 drops the data otherwise as
  north-aligned; ArduPilot ignores it);
- a sector's distance is the horizontal range (depth x sqrt(1 + tan^2 bearing)) of
  its nearest 2% of measured pixels; it is *confident* when at least ``min_coverage``
  of its pixels were measured (left-right checked, not WLS fill-in);
- confident and nearer than max: the range clamped to [min + 1, max] cm (min + 1 so
  PX4, which discards readings <= min, still sees it); confident and nothing within
  max: max + 1 ("no obstacle"); not confident: UINT16_MAX ("unknown"), never 0 and
  never "clear";
- a pass with no confident sector, or one whose frame is older than
  ``ranging.max_age_ms`` once computed, sends nothing (ArduPilot wipes its boundary on
  every message and reads UINT16_MAX as nothing there: silence is the only "I don't know").
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.keys import Key
from uav_depth.core.params import StereoParams
from uav_depth.daemon.link.vocabulary import cm_down, wire_range_cm
from uav_depth.daemon.worker import NicedWorker

log = logging.getLogger("uav_depth.obstacles")

N_SECTORS = 72
UINT16_UNKNOWN = 65535
MAV_FRAME_BODY_FRD = 12
#: share of a sector's measured pixels nearer than its reported range (robust to stray pixels)
NEAR_QUANTILE = 0.02


@dataclass(frozen=True)
class ObstacleConfig:
    """The ``obstacle_distance:`` section of the run config."""

    enabled: bool = False
    rate_hz: float = 5.0
    scale: float = 0.5
    min_coverage: float = 0.3

    KEYS = (
        Key("enabled", "bool", False, "also send OBSTACLE_DISTANCE (72 sectors across the camera's horizontal "
            "field) from a cheap full-width pass; feed it to a proximity instance of its own"),
        Key("rate_hz", "float", 5.0, "most OBSTACLE_DISTANCE passes per second", 0.2, 20.0),
        Key("scale", "float", 0.5, "resolution of the full-width pass, fraction of the input", 0.125, 1.0),
        Key("min_coverage", "float", 0.3, "share of a sector's pixels that must be measured for it to count "
            "(else it is sent as unknown, UINT16_MAX)", 0.01, 1.0),
    )


@dataclass(frozen=True)
class Field:
    """The horizontal field of the rectified left camera: sector geometry in degrees, FRD (clockwise +)."""

    width: int
    focal_px: float
    cx: float

    # Pixel centres at integer x (OpenCV's convention, cx = (W - 1) / 2 when centred): the field's
    # edges are the outer edges of the first and last columns.
    @property
    def left_deg(self) -> float:
        return math.degrees(math.atan2(-0.5 - self.cx, self.focal_px))

    @property
    def right_deg(self) -> float:
        return math.degrees(math.atan2(self.width - 0.5 - self.cx, self.focal_px))

    @property
    def increment_deg(self) -> float:
        return (self.right_deg - self.left_deg) / N_SECTORS

    @property
    def angle_offset_deg(self) -> float:
        """Bearing of the centre of element 0 (both autopilots read it as the centre)."""
        return self.left_deg + self.increment_deg / 2

    def sector_of_column(self) -> np.ndarray:
        """(W,) int sector index of each pixel column (by the bearing of its centre)."""
        bearing = np.degrees(np.arctan2(np.arange(self.width) - self.cx, self.focal_px))
        return np.clip(((bearing - self.left_deg) / self.increment_deg).astype(int), 0, N_SECTORS - 1)

    def centre_deg(self, j: int) -> float:
        return self.angle_offset_deg + j * self.increment_deg


def sector_ranges(measured: np.ndarray, field: Field, fb_px_m: float, min_coverage: float,
                  row_step: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Per sector: (72,) float horizontal range in m (NaN where nothing was measured) and (72,) bool confident.

    ``measured``: (H, W) float32 disparity px of the left matcher (NaN where not matched),
    at the field's resolution; ``fb_px_m``: focal length x baseline.
    """
    d = measured[::row_step]
    h, w = d.shape
    cols = field.sector_of_column()
    tan = (np.arange(w) - field.cx) / field.focal_px
    with np.errstate(divide="ignore", invalid="ignore"):
        rng = fb_px_m / d * np.sqrt(1.0 + tan ** 2)[None, :]
    rng[~(d > 0)] = np.nan
    out = np.full(N_SECTORS, np.nan)
    confident = np.zeros(N_SECTORS, bool)
    for j in range(N_SECTORS):
        block = rng[:, cols == j]
        if block.size == 0:
            continue
        vals = block[np.isfinite(block)]
        if vals.size:
            out[j] = float(np.quantile(vals, NEAR_QUANTILE))
        confident[j] = vals.size >= min_coverage * block.size
    return out, confident


def bins_cm(ranges_m: np.ndarray, confident: np.ndarray, min_cm: int, max_cm: int) -> list[int]:
    """The 72 ``distances`` of the message (see the module docstring for each case)."""
    out = []
    for r, ok in zip(ranges_m, confident):
        if not ok or not math.isfinite(r):
            out.append(UINT16_UNKNOWN)
        elif r * 100.0 > max_cm:
            out.append(max_cm + 1)
        else:
            out.append(int(min(max_cm, max(min_cm + 1, cm_down(r)))))   # rounded down: never farther
    return out


def limits_cm(min_distance_m: float, max_distance_m: float) -> tuple[int, int]:
    """(min, max) cm as DISTANCE_SENSOR carries them (link.vocabulary.wire_range_cm), max <= 65533."""
    min_cm, max_cm = wire_range_cm(min_distance_m, max_distance_m)
    return min_cm, min(max_cm, 65533)


def pass_params(params: StereoParams, scale: float) -> StereoParams:
    """The cheap full-width pass: the flying parameters over the whole frame at ``scale``, no WLS.

    ``sgbm.*`` count matched pixels, so the search range is scaled with the resolution (rounded up
    to OpenCV's multiple of 16): the pass sees the same distances as the flying parameters, and the
    band at the left edge SGBM cannot match (the search range wide) stays as narrow as it can.
    Its sectors are sent as unknown.
    """
    sg = params.sgbm
    scale = min(scale, params.compute.scale) if params.compute.scale < 1 else scale
    ratio = scale / params.compute.scale
    num = max(16, int(math.ceil(sg.num_disparities * ratio / 16.0)) * 16)
    return params.replace(**{"compute.roi": (0.0, 0.0, 1.0, 1.0), "compute.scale": scale, "wls.enabled": False,
                             "sgbm.num_disparities": num,
                             "sgbm.min_disparity": int(math.floor(sg.min_disparity * ratio))})


@dataclass(frozen=True)
class ObstacleReport:
    """One OBSTACLE_DISTANCE message's fields."""

    time_usec: int
    distances: list[int]
    increment: int
    increment_f: float
    angle_offset: float
    min_distance: int
    max_distance: int
    frame: int = MAV_FRAME_BODY_FRD


class ObstacleSender(NicedWorker):
    """The pass thread. ``offer`` (stereo loop: references, one assignment), ``start``, ``join``.

    ``send``: sends one :class:`ObstacleReport` (the link); ``params``: the current
    StereoParams; ``limits_cm``: the (min, max) cm of DISTANCE_SENSOR.
    """

    NAME = "obstacles"
    NICENESS = 10

    def __init__(self, config: ObstacleConfig, field: Field, fb_px_m: float, max_age_s: float,
                 params: Callable[[], StereoParams], limits_cm: Callable[[], tuple[int, int]],
                 send: Callable[[ObstacleReport], object], t_start: float, clock: Callable[[], float] = time.monotonic):
        self.config, self.field, self.fb_px_m, self.max_age_s = config, field, fb_px_m, max_age_s
        self.params, self.limits_cm, self.send, self.t_start, self.clock = params, limits_cm, send, t_start, clock
        self._pair: tuple[np.ndarray, np.ndarray, float] | None = None
        self._new = threading.Event()
        self._pipe: tuple[StereoParams, DisparityPipeline] | None = None
        self.sent = 0
        self.withheld = 0
        self.last: ObstacleReport | None = None

    def offer(self, left: np.ndarray, right: np.ndarray, t_capture: float) -> None:
        self._pair = (left, right, t_capture)
        self._new.set()

    def compute(self, left: np.ndarray, right: np.ndarray, t_capture: float) -> ObstacleReport | None:
        """One pass; None when no sector is confident or the frame got too old meanwhile."""
        params = pass_params(self.params(), self.config.scale)
        if self._pipe is None or self._pipe[0] != params:
            self._pipe = (params, DisparityPipeline(params))
        result = self._pipe[1].run(left, right)
        ranges, confident = sector_ranges(result.measured, self.field, self.fb_px_m, self.config.min_coverage)
        if not confident.any() or self.clock() - t_capture > self.max_age_s:
            return None
        lo, hi = self.limits_cm()
        inc = self.field.increment_deg
        return ObstacleReport(int((t_capture - self.t_start) * 1e6), bins_cm(ranges, confident, lo, hi),
                              max(1, int(round(inc))), inc, self.field.angle_offset_deg, lo, hi)


    def _loop(self, stop: threading.Event) -> None:
        period = 1.0 / self.config.rate_hz
        while not stop.is_set():
            t0 = self.clock()
            if not self._new.wait(0.2):
                continue
            self._new.clear()
            pair = self._pair
            if pair is None:
                continue
            try:
                report = self.compute(*pair)
            except Exception:   # one failed pass must not end the thread
                log.exception("obstacle pass failed")
                report = None
            if report is None:
                self.withheld += 1
            else:
                self.send(report)
                self.last = report
                self.sent += 1
            stop.wait(max(0.0, period - (self.clock() - t0)))


def encoder(report: ObstacleReport, sensor_type: int) -> Callable[[object], object]:
    """The ``build(mav)`` for :meth:`MavlinkLink.send`: OBSTACLE_DISTANCE from a report."""
    return lambda mav: mav.obstacle_distance_encode(
        report.time_usec, sensor_type, report.distances, report.increment, report.min_distance,
        report.max_distance, report.increment_f, report.angle_offset, report.frame)
