"""The UVC source: a ZED Mini (side-by-side stereo over UVC) or two cameras, through OpenCV's V4L2 backend.

A ZED Mini without the ZED SDK is a UVC camera that delivers both eyes in one
frame, left half then right half (2560x720 for two 1280x720 eyes). ``right_device``
switches to two separate V4L2 devices, grabbed back to back so the pair is as
close in time as V4L2 allows; a pair whose buffer timestamps lie more than half a
frame period apart (unsynchronised eyes) is dropped and counted in the status line. Frames are raw: rectification needs a calibration,
either the run config's ``calibration:`` or the ZED's own ``SN<serial>.conf``
(``zed_calibration``), read here without the ZED SDK.

No camera present: ``open()`` fails at once with the device path it looked for
and the video devices it did find.
"""

from __future__ import annotations

import configparser
import glob
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.keys import Key, section_values
from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError, SourceError
from uav_depth.core.fileio import read_text_file
from uav_depth.core.yamlfile import MAX_YAML_BYTES
from uav_depth.core.frames import Frame, device_capture_time


def _check_device(value: Any) -> str | None:
    if isinstance(value, bool) or not (isinstance(value, int) and value >= 0 or isinstance(value, str) and value):
        return "must be a V4L2 index (0, 1, ...) or a device path (/dev/video0)"
    return None


@dataclass(frozen=True)
class Config:
    KIND = "uvc"
    SOURCE_CLASS = "UvcSource"      # the class create_source() builds from this config
    KEYS = (
        Key("device", "any", 0, "V4L2 index or path of the (side-by-side) camera", check=_check_device,
            accepts="index or /dev path"),
        Key("right_device", "any", None, "second camera for the right eye; null: side-by-side in one frame",
            optional=True, check=_check_device, accepts="index or /dev path"),
        Key("width", "int", 1280, "width of one eye, px (a side-by-side frame is twice as wide)", 16, 8192),
        Key("height", "int", 720, "height, px", 16, 8192),
        Key("fps", "float", 30.0, "requested frame rate", 1.0, 240.0),
        Key("fourcc", "str", None, "pixel format to request (YUYV, MJPG); null: the driver's default",
            optional=True, check=lambda v: None if len(v) == 4 else "must be four characters"),
        Key("zed_calibration", "path", None, "a ZED SN<serial>.conf calibration file (raw K, D, R, T)",
            optional=True),
        Key("grey", "bool", True, "convert to grey before matching (cheaper; colour matching is the default "
            "of OpenCV's sample)"),
    )

    device: Any = 0
    right_device: Any = None
    width: int = 1280
    height: int = 720
    fps: float = 30.0
    fourcc: str | None = None
    zed_calibration: Path | None = None
    grey: bool = True

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | None = None, base_dir: Path | None = None,
                  origin: Mapping[str, str] | None = None) -> "Config":
        values = section_values(cls.KEYS, data, "source", source, origin=origin)
        zc = values["zed_calibration"]
        if zc is not None and not zc.is_absolute() and base_dir is not None:
            values["zed_calibration"] = base_dir / zc
        if values["right_device"] is not None and values["right_device"] == values["device"]:
            raise ConfigError("source.right_device", "must differ from source.device", values["right_device"], source)
        return cls(**values)


def device_path(device: Any) -> str:
    return f"/dev/video{device}" if isinstance(device, int) else str(device)


def split_side_by_side(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, 2W[, C]) side-by-side frame -> left (H, W[, C]), right (H, W[, C]) views (no copy)."""
    if frame.shape[1] % 2:
        raise SourceError(f"uvc: side-by-side frame width {frame.shape[1]} is odd; is this a stereo camera?")
    w = frame.shape[1] // 2
    return frame[:, :w], frame[:, w:]


#: ZED resolution names by the width of one eye.
ZED_RESOLUTIONS = {2208: "2K", 1920: "FHD", 1280: "HD", 672: "VGA"}


def read_zed_conf(path: str | os.PathLike[str], width: int, height: int) -> Calibration:
    """Raw calibration (K, D, R, T) of a ZED ``SN<serial>.conf`` file for one eye's size.

    The file (an INI) has ``[LEFT_CAM_HD]``/``[RIGHT_CAM_HD]`` with fx, fy, cx, cy,
    k1, k2, p1, p2, k3 and ``[STEREO]`` with Baseline (mm), TY/TZ (mm) and the
    rotation as a Rodrigues vector (RX, CV, RZ), per resolution (``CV_HD``).
    T is returned in metres, the unit of ``baseline_m``.
    """
    import cv2

    path = Path(path)
    res = ZED_RESOLUTIONS.get(width)
    if res is None:
        raise CalibrationError(f"{path}: a ZED calibration covers eye widths {sorted(ZED_RESOLUTIONS)}, "
                               f"but the camera delivers {width}")
    parser = configparser.ConfigParser()
    try:
        parser.read_string(read_text_file(path, "ZED calibration file", MAX_YAML_BYTES), str(path))
    except FileFormatError as exc:     # missing, not a regular file, too large, not UTF-8: one line
        raise CalibrationError(str(exc)) from exc
    except configparser.Error as exc:
        raise CalibrationError(f"{path}: not a ZED calibration file ({exc})") from exc

    def num(section: str, *names: str, default: float | None = None) -> float:
        for name in names:
            if parser.has_option(section, name):
                try:
                    return float(parser.get(section, name))
                except ValueError as exc:
                    raise CalibrationError(f"{path}: [{section}] {name} is not a number") from exc
        if default is not None:
            return default
        raise CalibrationError(f"{path}: [{section}] lacks {names[0]}")

    cams = {}
    for side in ("LEFT", "RIGHT"):
        sec = f"{side}_CAM_{res}"
        if not parser.has_section(sec):
            raise CalibrationError(f"{path}: no [{sec}] section for {width}x{height} eyes")
        k = ((num(sec, "fx"), 0.0, num(sec, "cx")), (0.0, num(sec, "fy"), num(sec, "cy")), (0.0, 0.0, 1.0))
        d = tuple(num(sec, n, default=0.0) for n in ("k1", "k2", "p1", "p2", "k3"))
        cams[side] = (k, d)
    if not parser.has_section("STEREO"):
        raise CalibrationError(f"{path}: no [STEREO] section")
    baseline_mm = num("STEREO", "Baseline", "BaseLine")
    ty = num("STEREO", f"TY_{res}", "TY", default=0.0)
    tz = num("STEREO", f"TZ_{res}", "TZ", default=0.0)
    rvec = np.array([num("STEREO", f"RX_{res}", "RX", default=0.0), num("STEREO", f"CV_{res}", "CV", default=0.0),
                     num("STEREO", f"RZ_{res}", "RZ", default=0.0)])
    rot, _ = cv2.Rodrigues(rvec)
    # OpenCV's T maps left-camera points into the right camera: the right eye sits at +x, so T_x < 0.
    t = (-baseline_mm / 1000.0, ty / 1000.0, tz / 1000.0)
    return Calibration(focal_px=cams["LEFT"][0][0][0], baseline_m=baseline_mm / 1000.0, width=width, height=height,
                       k_left=cams["LEFT"][0], d_left=cams["LEFT"][1], k_right=cams["RIGHT"][0],
                       d_right=cams["RIGHT"][1], r=tuple(map(tuple, rot)), t=t,
                       extra={"source_file": str(path)})


class UvcSource:
    kind = "uvc"

    def __init__(self, config: Config, stop_event: threading.Event | None = None, **_: Any):
        self.config = config
        self.calibration: Calibration | None = None
        self._caps: list[Any] = []
        self._index = 0
        self._period_s = 1.0 / config.fps
        self.out_of_sync = 0        # two-camera pairs dropped: the eyes were captured too far apart

    @property
    def notes(self) -> tuple[str, ...]:
        """For the status line: the pairs dropped because the two cameras' exposures were apart."""
        n = self.out_of_sync
        return (f"{n} stereo pair{'s' * (n != 1)} dropped (eyes captured more than half a frame apart)",) if n else ()

    def describe(self) -> str:
        c = self.config
        what = (f"{device_path(c.device)} + {device_path(c.right_device)}" if c.right_device is not None
                else f"{device_path(c.device)} side by side")
        return f"uvc {what}, {c.width}x{c.height} per eye at {c.fps:g} fps"

    def open(self) -> None:
        c = self.config
        devices = [c.device] if c.right_device is None else [c.device, c.right_device]
        if c.zed_calibration is not None:   # a config fault first (exit 78), not after waiting for the camera
            self.calibration = read_zed_conf(c.zed_calibration, c.width, c.height)
        for dev in devices:
            path = device_path(dev)
            if not os.path.exists(path):
                found = sorted(glob.glob("/dev/video*"))
                raise SourceError(f"uvc: camera {path} not found (video devices present: "
                                  f"{', '.join(found) if found else 'none'}); is the camera plugged in?")
        import cv2

        sbs = c.right_device is None
        for dev in devices:
            path = device_path(dev)
            cap = cv2.VideoCapture(dev if isinstance(dev, int) else path, cv2.CAP_V4L2)
            if not cap.isOpened():
                self.close()
                raise SourceError(f"uvc: cannot open {path} through V4L2 (busy, or no permission: is the user in "
                                  "the video group?)")
            if c.fourcc:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*c.fourcc))
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, c.width * (2 if sbs else 1))
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, c.height)
            cap.set(cv2.CAP_PROP_FPS, c.fps)
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)   # newest frame, not a queue of old ones
            got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            want = (c.width * (2 if sbs else 1), c.height)
            self._caps.append(cap)
            if got != want:
                self.close()
                raise SourceError(f"uvc: {path} delivers {got[0]}x{got[1]}, but {want[0]}x{want[1]} was requested"
                                  f"{' (two eyes side by side)' if sbs else ''}; set source.width/height to a mode "
                                  "the camera supports")
        self._index = 0
        fps = self._caps[0].get(cv2.CAP_PROP_FPS)
        self._period_s = 1.0 / (fps if fps and fps > 0 else c.fps)

    def close(self) -> None:
        for cap in self._caps:
            try:
                cap.release()
            except Exception:  # releasing a vanished device must not stop the reconnect loop
                pass
        self._caps = []

    def read(self, timeout_s: float) -> Frame | None:
        import cv2

        if not self._caps:
            raise SourceError("uvc: read() before open()")
        for cap in self._caps:
            cap.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, max(1.0, timeout_s * 1000.0))
        # grab all, then decode: the two exposures are as close as V4L2 allows
        if not all(cap.grab() for cap in self._caps):
            raise SourceError(f"uvc: {device_path(self.config.device)} stopped delivering frames (unplugged?)")
        now = time.monotonic()
        # V4L2 buffer timestamps (CLOCK_MONOTONIC for UVC) through CAP_PROP_POS_MSEC; a driver on another
        # clock gives implausible values and the receive time is used instead
        stamps = [cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0 or None for cap in self._caps]
        if len(stamps) == 2 and None not in stamps and abs(stamps[0] - stamps[1]) > self._period_s / 2:
            # Two free-running cameras: a pair exposed this far apart turns motion into disparity error
            # (farther included), so it is dropped and counted, never matched.
            self.out_of_sync += 1
            return None
        t_capture = device_capture_time(stamps, now)
        images = []
        for cap in self._caps:
            ok, img = cap.retrieve()
            if not ok or img is None:
                raise SourceError(f"uvc: {device_path(self.config.device)} returned an empty frame")
            images.append(img)
        left, right = split_side_by_side(images[0]) if len(images) == 1 else (images[0], images[1])
        if self.config.grey and left.ndim == 3:
            left = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
            right = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
        else:
            left, right = np.ascontiguousarray(left), np.ascontiguousarray(right)
        self._index += 1
        return Frame(left=left, right=right, index=self._index - 1, t_capture=t_capture)
