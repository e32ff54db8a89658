"""``uav-depth run --check``: load everything ``run`` would load, start nothing.

The same functions as the service, in the same order of concern: the signing key
(:func:`~uav_depth.daemon.link.signing.load_signing_key`), the MAVLink link (opened
and closed at once: :func:`~uav_depth.daemon.link.urls.try_open`; one that cannot be
opened, which ``run`` would retry for ever, raises LinkError: exit 69), the log directory
(:func:`~uav_depth.daemon.framelog.ensure_log_dir`), the calibration
(:func:`~uav_depth.daemon.stage.resolve_calibration`), the parameter file with every
rule the daemon applies at start-up (:meth:`~uav_depth.daemon.stage.StageHolder.open`:
the schema, OpenCV's limits at this image size, the test render in a child process), and the frame
source. What ``run`` refuses, this raises, with the same exception (so the same
exit code); what ``run`` would only warn about comes back as a warning.

Hardware sources are not opened (a running daemon may hold the camera): their
presence is checked (a V4L2 device node, an OAK device that depthai can see) and
its absence is a warning. A replay (or synthetic) source is opened and closed:
its files are what it would read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import LinkError, SourceError
from uav_depth.core.params import load_params
from uav_depth.core.rectify import Rectifier
from uav_depth.daemon.config import RunConfig
from uav_depth.daemon.framelog import ensure_log_dir, free_mb
from uav_depth.daemon.link.signing import load_signing_key
from uav_depth.daemon.link.urls import try_open
from uav_depth.core.ranging import RangeLimits, resolve_roi
from uav_depth.daemon.sources import FrameSource
from uav_depth.daemon.sources.oak import find_devices, import_depthai
from uav_depth.daemon.sources.uvc import device_path, read_zed_conf
from uav_depth.daemon.stage import StageHolder, resolve_calibration
from uav_depth.daemon.trial import Trials

HARDWARE = ("uvc", "oak")


@dataclass
class Preflight:
    """What was checked (``checked``: one line each), what ``run`` would warn about, and the range the
    parameters measure (``limits``: what DISTANCE_SENSOR states; None when the calibration comes from
    the device at start-up)."""

    checked: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    limits: RangeLimits | None = None


def _hardware_calibration(config: RunConfig, report: Preflight) -> Calibration | None:
    """The calibration a hardware source would carry, where it can be read without the device."""
    src = config.source
    if config.source_kind == "uvc":
        for dev in (src.device, src.right_device):
            if dev is not None and not os.path.exists(device_path(dev)):
                report.warnings.append(f"camera {device_path(dev)} is not present now (run waits for it: exit 69, "
                                       "systemd retries)")
        return read_zed_conf(src.zed_calibration, src.width, src.height) if src.zed_calibration else None
    dai = import_depthai()          # DependencyError: run would fail the same way
    try:
        find_devices(dai, src.device_id)
    except SourceError as exc:
        report.warnings.append(f"{exc} (run waits for it: exit 69, systemd retries)")
    return None


def preflight(config: RunConfig, source: FrameSource) -> Preflight:
    """Check ``config`` as ``run`` would, with ``source`` built (not opened) from it. Raises what run raises."""
    report = Preflight()
    mav = config.mavlink
    if mav.signing_key_file is not None:
        load_signing_key(mav.signing_key_file)
        report.checked.append(f"signing key {mav.signing_key_file}")
    problem, note = try_open(mav.url, mav.baud, mav.bind_address)
    if problem is not None:
        raise LinkError(f"{problem}: run would retry every 0.25 s and send nothing")
    report.checked.append(f"link {mav.url}" + ("" if note else " opens"))
    if note is not None:
        report.warnings.append(note)
    log = config.logging
    if log.dir is not None:
        ensure_log_dir(log.dir)
        free = free_mb(log.dir)
        report.checked.append(f"log directory {log.dir} writable, {free:.0f} MB free")
        if free < log.min_free_mb:
            report.warnings.append(f"{log.dir}: {free:.0f} MB free, below logging.min_free_mb {log.min_free_mb:g}: "
                                   "no frame would be logged")
    if config.source_kind in HARDWARE:
        carried = _hardware_calibration(config, report)
        report.checked.append(f"source {source.describe()} (not opened)")
    else:
        source.open()               # SourceError (a missing replay path, no frames): run exits 69 on it too
        try:
            carried = source.calibration
            report.checked.append(f"source {source.describe()}")
        finally:
            source.close()
    if config.calibration is None and carried is None and config.source_kind == "oak":
        report.warnings.append("calibration: read from the OAK at start-up; the parameter file was checked "
                               "against the schema only")
        if config.params_file is not None and config.params_file.exists():
            load_params(config.params_file)
        return report
    calib = resolve_calibration(config.calibration, carried, config.source_kind)
    rectified = Rectifier(calib).calibration
    roi = resolve_roi(config.ranging.roi, rectified.width, rectified.height)
    report.checked.append(f"calibration f {rectified.focal_px:.1f} px, B {rectified.baseline_m:.4f} m, "
                          f"{rectified.width}x{rectified.height}")
    if config.params_file is not None and not config.params_file.exists():
        report.warnings.append(f"parameter file {config.params_file} does not exist: run would send nothing "
                               "(blind: parameters unusable) until it appears")
    holder = StageHolder(str(config.params_file) if config.params_file else None, config.ranging,
                         statustext=lambda text, severity: None, trials=Trials(config.service.trial_timeout_s))
    try:
        stage = holder.open(rectified, roi)
    finally:
        holder.close()
    report.limits = stage.ranger.limits
    report.checked.append(f"parameters {stage.origin}: hash {stage.hash}, measure a test render in ROI {list(roi)} "
                          "(run in a child process)")
    return report
