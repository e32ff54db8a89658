"""The stereo stage: what one parameter set builds (pipeline + ranger), and its hot reload.

:class:`Stage` is swapped as a whole by one attribute assignment, so the stereo
thread (which reads it once per frame) never sees half of a new parameter set.
:class:`StageHolder` owns the current stage, builds it from the parameter file at
start-up and rebuilds it on reload; a file that cannot be used keeps the last
good stage and says so in one line.
"""

from __future__ import annotations

import functools
import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityPipeline, flight_pipeline
from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams, load_params
from uav_depth.daemon.ranging import Ranger, RangingConfig
from uav_depth.daemon.reload import file_signature

log = logging.getLogger("uav_depth.service")

#: ``statustext(text, severity)``: how the stage tells the autopilot about a reload.
StatusText = Callable[[str, str], object]


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


def build_stage(params: StereoParams, origin: str, ranging: RangingConfig, calibration: Calibration,
                roi: tuple[int, int, int, int]) -> Stage:
    """Build the stage for ``params`` (warns when the ranging ROI leaves the matching region)."""
    ranger = Ranger(ranging, calibration, roi, params)
    warning = check_roi_against_compute(roi, params, calibration.width, calibration.height)
    if warning:
        log.warning("%s", warning)
    return Stage(params, flight_pipeline(params), ranger, origin)


class StageHolder:
    """The current :class:`Stage` and the parameter file it came from.

    ``params_file``: None runs the built-in manual defaults; ``statustext``: how a
    reload is reported to the autopilot.
    """

    def __init__(self, params_file: str | None, ranging: RangingConfig, statustext: StatusText):
        self.params_file = Path(params_file) if params_file is not None else None
        self.ranging = ranging
        self.statustext = statustext
        self.stage: Stage | None = None
        self.signature: tuple[int, int, int] | None = None   # the file as last read (for the watcher)
        self._calibration: Calibration | None = None
        self._roi: tuple[int, int, int, int] | None = None
        self._lock = threading.Lock()

    def _initial_params(self) -> tuple[StereoParams, str]:
        path = self.params_file
        if path is None:
            return DEFAULT_PARAMS, "built-in manual defaults"
        self.signature = file_signature(path)   # what the watcher compares against
        if not path.exists():
            log.warning("parameter file %s does not exist: using the built-in manual defaults until it appears",
                        path)
            return DEFAULT_PARAMS, "built-in manual defaults"
        return load_params(path), str(path)

    def open(self, calibration: Calibration, roi: tuple[int, int, int, int]) -> Stage:
        """Build the first stage (raises ConfigError/FileFormatError/CalibrationError when it cannot)."""
        self._calibration, self._roi = calibration, roi
        params, origin = self._initial_params()
        self.stage = self.build(params, origin)
        return self.stage

    def build(self, params: StereoParams, origin: str) -> Stage:
        assert self._calibration is not None and self._roi is not None
        return build_stage(params, origin, self.ranging, self._calibration, self._roi)

    def reload(self, path: Path | None = None) -> bool:
        """Re-read the parameter file; swap the stage if it is valid and new. Never raises.

        Invalid file: the last good parameters stay, one log line names the problem,
        a STATUSTEXT says so. Returns True when a new stage was swapped in.
        """
        path = Path(path) if path is not None else self.params_file
        if path is None or self.stage is None:
            return False
        with self._lock:
            current = self.stage
            if not path.exists():
                log.warning("parameter file %s removed; keeping parameters %s", path, current.hash)
                return False
            try:
                params = load_params(path)
                if params == current.params:
                    log.info("parameter file %s rewritten with the same parameters (hash %s)", path, current.hash)
                    return False
                stage = self.build(params, str(path))
            except (ConfigError, FileFormatError, CalibrationError) as exc:
                log.error("parameters rejected, keeping %s: %s", current.hash, exc)
                self.statustext(f"uav-depth: params rejected, kept {current.hash[:8]}", "warning")
                return False
            self.stage = stage      # the swap: the stereo thread picks it up at its next frame
            log.info("parameters reloaded from %s: hash %s (was %s)", path, stage.hash, current.hash)
            self.statustext(f"uav-depth: params {stage.hash[:8]} loaded", "info")
            return True
