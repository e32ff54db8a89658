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
import math
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.disparity import DisparityPipeline, flight_pipeline
from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError, ParameterWarning
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams, check_image_size, load_params
from uav_depth.core.ranging import RangeLimits, Ranger, RangingConfig
from uav_depth.daemon.reload import file_signature, wait_until_complete
from uav_depth.daemon.trial import Job, Trials

log = logging.getLogger("uav_depth.service")

#: At start-up, how long a parameter file still being written is waited for before it is read anyway.
STARTUP_WAIT_S = 10.0
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


def test_render(stage: Stage, width: int, height: int, seed: int = 0) -> tuple[str | None, float]:
    """Measure a test render: a fronto-parallel random texture filling the view at a distance the
    stage should read. Returns (why it measured nothing, or None; the distance rendered, m).

    This is the first-use check of a parameter set: the easiest scene SGBM can be
    given (every pixel textured, one integer disparity inside the search range and
    the ranging limits). Parameters that measure nothing here measure nothing in
    flight (penalties out of range, a search range the ROI cannot use, a
    uniqueness or speckle setting that removes every match), so they are refused.
    """
    ranger, sg = stage.ranger, stage.params.sgbm
    d_max = (sg.min_disparity + sg.num_disparities - 1) * ranger.px
    d = int(round(min(max(0.4 * d_max, 2.0 * ranger.d_floor), 0.9 * d_max)))
    d = max(d, int(math.ceil(ranger.d_floor)) + 1)
    z = ranger.fb / d
    x0, y0, x1, y1 = ranger.roi
    if stage.params.compute.whole_frame:
        # Whole-frame matching: render only the ROI plus what SGBM needs around it (the search
        # range to the left, a block all round), which is all that reaches the ROI's pixels.
        pad = int(math.ceil((sg.block_size + 8) * ranger.px))
        cx0 = max(0, x0 - int(math.ceil((sg.min_disparity + sg.num_disparities) * ranger.px)) - pad)
        need = int(math.ceil((sg.min_disparity + sg.num_disparities + sg.block_size // 2 + 2) * ranger.px))
        cy0, cx1, cy1 = max(0, y0 - pad), min(width, max(x1 + pad, cx0 + need)), min(height, y1 + pad)
        ranger = Ranger(ranger.config, ranger.calibration, (x0 - cx0, y0 - cy0, x1 - cx0, y1 - cy0), stage.params)
        width, height = cx1 - cx0, cy1 - cy0
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 256, (height, width + d), dtype=np.uint8), (0, 0), 0.7)
    left, right = np.ascontiguousarray(base[:, :width]), np.ascontiguousarray(base[:, d:d + width])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ParameterWarning)
        try:
            m = ranger.measure(stage.pipeline.run(left, right))
        except cv2.error as exc:   # OpenCV's own refusal, as one line
            return f"OpenCV refused: {' '.join(str(exc).split())[:200]}", z
    return (None if m.valid else m.reason or "no measurement"), z


def make_stage(params: StereoParams, origin: str, ranging: RangingConfig, calibration: Calibration,
               roi: tuple[int, int, int, int]) -> Stage:
    """The stage of ``params`` for this camera and ranging ROI, unchecked (see :func:`build_stage`)."""
    return Stage(params, flight_pipeline(params), Ranger(ranging, calibration, roi, params), origin)


def build_stage(params: StereoParams, origin: str, ranging: RangingConfig, calibration: Calibration,
                roi: tuple[int, int, int, int], trials: Trials | None = None) -> Stage:
    """Build the stage for ``params`` and check that it can measure; ConfigError when it cannot.

    Refused: parameters that cannot match anything at this image size
    (:func:`~uav_depth.core.params.check_image_size`) and parameters that measure
    nothing on :func:`test_render`. Warns when the ranging ROI leaves the matching region.
    ``trials``: run the test render in that child process (:mod:`uav_depth.daemon.trial`), so
    that an OpenCV crash on new parameters refuses them instead of ending this process; None
    runs it here (benchmarks and tools that may crash with it).
    """
    w, h = calibration.width, calibration.height
    check_image_size(params, w, h, origin)
    try:
        stage = make_stage(params, origin, ranging, calibration, roi)
    except ConfigError:
        raise
    except Exception as exc:   # a combination no rule foresaw: one line naming the file, not a traceback
        raise ConfigError("(parameters)", "must build a flight stage", f"{type(exc).__name__}: {exc}",
                          origin) from exc
    warning = check_roi_against_compute(roi, params, w, h)
    if warning:
        log.warning("%s", warning)
    if trials is not None:
        outcome = trials.run(Job(params, origin, ranging, calibration, roi))
        why, z = outcome.why, outcome.distance_m
    else:
        why, z = test_render(stage, w, h)
    if why is not None:
        raise ConfigError("(parameters)", f"must measure a test render (random texture filling the view at "
                          f"{z:.2f} m, {w}x{h}, ranging ROI {list(roi)}); they measured nothing", why, origin)
    return stage


def resolve_calibration(configured: Calibration | None, carried: Calibration | None, kind: str) -> Calibration:
    """The calibration the daemon uses: the config's, else the one the source carries; CalibrationError if none."""
    calib = configured or carried
    if calib is None:
        raise CalibrationError(f"source {kind} carries no calibration: set calibration: FILE "
                               "(focal_px, baseline_m, width, height; K, D, R, T for raw frames)")
    if configured is not None and carried is not None and configured != carried:
        log.warning("the config's calibration overrides the one the %s source carries", kind)
    return calib


class StageHolder:
    """The current :class:`Stage` and the parameter file it came from.

    ``params_file``: None runs the built-in manual defaults; ``statustext``: how a
    reload is reported to the autopilot; ``trials``: the child process every new
    parameter set is first run in (:mod:`uav_depth.daemon.trial`; default: its own).
    Written by one thread at a time: :meth:`open` before the watcher starts, then
    :meth:`reload` on the watcher's thread only.
    """

    def __init__(self, params_file: str | None, ranging: RangingConfig, statustext: StatusText,
                 stop: threading.Event | None = None, trials: Trials | None = None):
        self.params_file = Path(params_file) if params_file is not None else None
        self.ranging = ranging
        self.statustext = statustext
        self.stop = stop or threading.Event()
        self.trials = trials if trials is not None else Trials()
        self.rejected: str | None = None   # why the newest file was refused (None: it is what flies)
        self.stage: Stage | None = None
        self.signature: tuple[int, int, int] | None = None   # the file as last read (for the watcher)
        self._calibration: Calibration | None = None
        self._roi: tuple[int, int, int, int] | None = None
        self._judged: tuple[int, ...] | None = None   # the file as last judged (loaded or refused)
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
        wait_until_complete(path, self.stop, timeout_s=STARTUP_WAIT_S)
        self.signature = file_signature(path)
        self._judged = _identity(path)
        return load_params(path), str(path)

    def open(self, calibration: Calibration, roi: tuple[int, int, int, int]) -> Stage:
        """Build the first stage (raises ConfigError/FileFormatError/CalibrationError when it cannot)."""
        self._calibration, self._roi = calibration, roi
        params, origin = self._initial_params()
        self.stage = self.build(params, origin)
        return self.stage

    def build(self, params: StereoParams, origin: str) -> Stage:
        """The checked stage of ``params``, its test render run in the child process."""
        assert self._calibration is not None and self._roi is not None
        return build_stage(params, origin, self.ranging, self._calibration, self._roi, self.trials)

    def params(self) -> StereoParams:
        """The parameters flying now (after :meth:`open`)."""
        assert self.stage is not None
        return self.stage.params

    def limits(self) -> RangeLimits:
        """The range the current stage states on the wire (after :meth:`open`)."""
        assert self.stage is not None
        return self.stage.ranger.limits

    def close(self) -> None:
        """End the trial child (a trial in progress fails, quietly once ``stop`` is set)."""
        self.trials.close()

    def reload(self, path: Path | None = None) -> bool:
        """Re-read the parameter file; swap the stage if it is valid and new. Never raises.

        The file is read once it is complete (:func:`~uav_depth.daemon.reload.wait_until_complete`),
        and only when it changed since it was last judged (a SIGHUP and the watch both
        seeing one change judge it once). Invalid file (unreadable, not UTF-8, not YAML,
        anchors or aliases, over the size cap, a key twice, a rule broken, parameters that
        crash or hang OpenCV in the trial child or measure nothing on the test render): the
        last good parameters stay, one log line names the problem, a STATUSTEXT says so and
        :attr:`rejected` holds the reason. Returns True when a new stage was swapped in.
        """
        path = Path(path) if path is not None else self.params_file
        if path is None or self.stage is None:
            return False
        with self._lock:
            current = self.stage
            if not wait_until_complete(path, self.stop):
                return False
            if not path.exists():
                log.warning("parameter file %s removed; keeping parameters %s", path, current.hash)
                self._judged = None
                return False
            seen = _identity(path)
            if seen == self._judged:
                log.debug("parameter file %s unchanged since it was judged", path)
                return False
            self._judged = seen
            try:
                params = load_params(path)
                if params == current.params:
                    log.info("parameter file %s rewritten with the same parameters (hash %s)", path, current.hash)
                    return False
                stage = self.build(params, str(path))
            except (ConfigError, FileFormatError, CalibrationError) as exc:
                return self._reject(current, str(exc))
            except Exception as exc:   # never let a new file end the daemon: the last good stage flies on
                return self._reject(current, f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
            self.rejected = None
            self.stage = stage      # the swap: the stereo thread picks it up at its next frame
            log.info("parameters reloaded from %s: hash %s (was %s)", path, stage.hash, current.hash)
            self.statustext(f"uav-depth: params {stage.hash[:8]} loaded", "info")
            return True

    def _reject(self, current: Stage, why: str) -> bool:
        if self.stop.is_set():      # shutting down: the trial child was ended under the trial
            return False
        self.rejected = why
        log.error("parameters rejected, keeping %s: %s", current.hash, why)
        self.statustext(f"uav-depth: params rejected, kept {current.hash[:8]}", "warning")
        return False


def _identity(path: Path) -> tuple[int, ...] | None:
    """The file's identity for "judged already": inode, size, mtime and ctime (a chmod changes only ctime)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
