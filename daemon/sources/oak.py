"""The OAK source: a Luxonis OAK-D through depthai 3.x, rectified on the device.

The device's StereoDepth node rectifies both mono cameras (CAM_B left, CAM_C
right) and the source delivers that rectified pair with a rectified calibration
read from the device's EEPROM; our SGBM + WLS pipeline then matches them. With
``device_depth`` the device's own depth (aligned to the rectified left image) is
converted to disparity and carried as a reference, so logged sessions can be
scored and tuned against it (``reference_source: {kind: device}``).

depthai blocks for seconds in pipeline construction when no device is attached,
so ``open()`` first asks depthai which devices it can see and fails at once when
there is none.
"""

from __future__ import annotations

import datetime
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from uav_depth.core.calibration import Calibration
from uav_depth.core.keys import Key, section_values
from uav_depth.core.errors import DependencyError, SourceError
from uav_depth.core.frames import Frame, device_capture_time


@dataclass(frozen=True)
class Config:
    KIND = "oak"
    SOURCE_CLASS = "OakSource"      # the class create_source() builds from this config
    KEYS = (
        Key("device_id", "str", None, "device id (MxId / serial) to open; null: the first device found",
            optional=True),
        Key("width", "int", 1280, "rectified width, px", 16, 4096),
        Key("height", "int", 720, "rectified height, px", 16, 4096),
        Key("fps", "float", 30.0, "camera frame rate", 1.0, 240.0),
        Key("device_depth", "bool", False, "carry the device's own depth as reference disparity (logged for "
            "tuning)"),
    )

    device_id: str | None = None
    width: int = 1280
    height: int = 720
    fps: float = 30.0
    device_depth: bool = False

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | None = None, base_dir: Path | None = None,
                  origin: Mapping[str, str] | None = None) -> "Config":
        return cls(**section_values(cls.KEYS, data, "source", source, origin=origin))


def import_depthai() -> Any:
    try:
        import depthai as dai
    except ImportError as exc:
        raise DependencyError("depthai", "oak", "the oak source") from exc
    return dai


def find_devices(dai: Any, device_id: str | None) -> Any:
    """The DeviceInfo to open; SourceError at once when depthai sees no (matching) device."""
    devices = list(dai.Device.getAllAvailableDevices())
    if not devices:
        raise SourceError(f"oak: no OAK device found (depthai {getattr(dai, '__version__', '?')} searched USB and "
                          "the network); is it plugged in and powered? On Linux, USB access needs Luxonis' udev rule "
                          "(80-movidius.rules)")
    if device_id is None:
        return devices[0]
    for info in devices:
        if device_id in (info.getDeviceId(), getattr(info, "name", None)):
            return info
    raise SourceError(f"oak: device {device_id} not found (found: {', '.join(d.getDeviceId() for d in devices)})")


class OakSource:
    kind = "oak"

    def __init__(self, config: Config, stop_event: threading.Event | None = None, **_: Any):
        self.config = config
        self.calibration: Calibration | None = None
        self._device = None
        self._pipeline = None
        self._queues: dict[str, Any] = {}
        self._index = 0

    def describe(self) -> str:
        c = self.config
        return (f"oak {c.device_id or '(first device)'} {c.width}x{c.height} at {c.fps:g} fps"
                f"{', device depth as reference' if c.device_depth else ''}")

    def open(self) -> None:
        dai = import_depthai()
        info = find_devices(dai, self.config.device_id)
        c = self.config
        try:
            device = dai.Device(info)
            pipeline = dai.Pipeline(device)
            left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
            right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
            stereo = pipeline.create(dai.node.StereoDepth)
            size = (c.width, c.height)
            left.requestOutput(size, type=dai.ImgFrame.Type.GRAY8, fps=c.fps).link(stereo.left)
            right.requestOutput(size, type=dai.ImgFrame.Type.GRAY8, fps=c.fps).link(stereo.right)
            stereo.setRectification(True)
            stereo.setLeftRightCheck(True)
            stereo.setDepthAlign(dai.StereoDepthConfig.AlgorithmControl.DepthAlign.RECTIFIED_LEFT)
            queues = {"left": stereo.rectifiedLeft.createOutputQueue(maxSize=2, blocking=False),
                      "right": stereo.rectifiedRight.createOutputQueue(maxSize=2, blocking=False)}
            if c.device_depth:
                stereo.setSubpixel(True)
                queues["depth"] = stereo.depth.createOutputQueue(maxSize=2, blocking=False)
            calib = device.readCalibration()
            # depthai rectifies both eyes to the right camera's intrinsics (its "M2").
            k = np.asarray(calib.getCameraIntrinsics(dai.CameraBoardSocket.CAM_C, c.width, c.height), float)
            baseline_cm = calib.getBaselineDistance(dai.CameraBoardSocket.CAM_C, dai.CameraBoardSocket.CAM_B, False)
            pipeline.start()
        except RuntimeError as exc:
            raise SourceError(f"oak: cannot start {info.getDeviceId()}: {exc}") from exc
        self.calibration = Calibration(focal_px=float(k[0, 0]), baseline_m=abs(float(baseline_cm)) / 100.0,
                                       width=c.width, height=c.height, cx=float(k[0, 2]), cy=float(k[1, 2]),
                                       extra={"device_id": info.getDeviceId()})
        self._device, self._pipeline, self._queues = device, pipeline, queues
        self._index = 0

    def close(self) -> None:
        pipeline, device = self._pipeline, self._device
        self._pipeline = self._device = None
        self._queues = {}
        for thing in (pipeline, device):
            try:
                if thing is not None:
                    (thing.stop if hasattr(thing, "stop") else thing.close)()
            except Exception:  # the device may already be gone; reconnect must go on
                pass

    def read(self, timeout_s: float) -> Frame | None:
        if self._pipeline is None:
            raise SourceError("oak: read() before open()")
        if not self._pipeline.isRunning():
            raise SourceError("oak: the device pipeline stopped (device unplugged?)")
        timeout = datetime.timedelta(seconds=timeout_s)
        try:
            msgs = {name: q.get(timeout) for name, q in self._queues.items()}
        except RuntimeError as exc:
            raise SourceError(f"oak: lost the device ({exc})") from exc
        if any(m is None for m in msgs.values()):
            return None
        # the three streams come from one stereo run; their sequence numbers must match
        seqs = {m.getSequenceNum() for m in msgs.values()}
        if len(seqs) != 1:
            return None
        # getTimestamp(): the end of exposure on the host's steady clock (CLOCK_MONOTONIC), synced by depthai
        t_capture = device_capture_time([_stamp(msgs["left"]), _stamp(msgs["right"])], time.monotonic())
        left, right = msgs["left"].getFrame(), msgs["right"].getFrame()
        reference = None
        if "depth" in msgs:
            depth_mm = msgs["depth"].getFrame().astype(np.float32)
            assert self.calibration is not None
            with np.errstate(divide="ignore"):
                reference = np.where(depth_mm > 0, self.calibration.focal_px * self.calibration.baseline_m * 1000.0
                                     / depth_mm, np.nan).astype(np.float32)
        self._index += 1
        return Frame(left=left, right=right, index=self._index - 1, t_capture=t_capture, reference=reference,
                     reference_source=({"kind": "device", "device": "oak", "note": "OAK StereoDepth depth, "
                                        "converted to disparity with the rectified calibration"}
                                       if reference is not None else None))


def _stamp(msg: Any) -> float | None:
    """A depthai ImgFrame's capture time in monotonic s (None when it has none)."""
    try:
        return msg.getTimestamp().total_seconds()
    except (AttributeError, RuntimeError):
        return None
