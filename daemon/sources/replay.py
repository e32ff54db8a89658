"""The replay source: frames of a logged session (the log layout), paced like a camera.

Pacing: ``rate_hz`` when given; otherwise the frames' recorded ``time_s`` (which the
daemon's frame logger writes) when every frame has one, else 10 Hz. The truth
comes from each frame's ``branch_distance_m`` meta when present (synthetic
sessions). Without ``loop`` the source ends after the last frame and the daemon
stops cleanly, once the frames in flight are processed. With ``lossless`` the capture
thread waits for the pipeline instead of replacing an unprocessed frame (every frame
is processed; the replay runs as fast as the pipeline, never faster than its pacing).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from uav_depth.core.calibration import Calibration
from uav_depth.core.keys import Key, section_values
from uav_depth.core.errors import FileFormatError, SourceError
from uav_depth.core.session import FrameRecord, find_sessions
from uav_depth.core.frames import EndOfStream, Frame

DEFAULT_RATE_HZ = 10.0
log = logging.getLogger("uav_depth.sources.replay")


@dataclass(frozen=True)
class Config:
    KIND = "replay"
    SOURCE_CLASS = "ReplaySource"      # the class create_source() builds from this config
    KEYS = (
        Key("path", "path", None, "a session or a directory of sessions (log layout)"),
        Key("rate_hz", "float", None, "frames per second; null: recorded time_s, else 10", 0.01, 1000.0,
            optional=True),
        Key("loop", "bool", False, "start again after the last frame (else the daemon stops)"),
        Key("lossless", "bool", False, "process every frame: pacing waits for the pipeline instead of the "
            "newest frame replacing one not yet processed (for evaluating a logged flight; not real time)"),
    )

    path: Path
    rate_hz: float | None = None
    loop: bool = False
    lossless: bool = False

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | None = None, base_dir: Path | None = None,
                  origin: Mapping[str, str] | None = None) -> "Config":
        values = section_values(cls.KEYS, data, "source", source, origin=origin)
        if not values["path"].is_absolute() and base_dir is not None:
            values["path"] = base_dir / values["path"]
        return cls(**values)


def _recorded_time(record: FrameRecord) -> Any:
    """The frame's logged ``time_s``; None when its meta.json is unreadable (read() skips that frame)."""
    try:
        return record.load_meta().get("time_s")
    except FileFormatError:
        return None


class ReplaySource:
    kind = "replay"

    def __init__(self, config: Config, clock: Callable[[], float] = time.monotonic,
                 stop_event: threading.Event | None = None, **_: Any):
        self.config = config
        self.lossless = config.lossless     # read by the capture thread: wait for the pipeline
        self.clock = clock
        self._stop = stop_event or threading.Event()
        self.calibration: Calibration | None = None
        self._frames: list[FrameRecord] = []
        self._times: list[float] = []
        self._i = 0
        self._lap = 0
        self._t0: float | None = None

    def describe(self) -> str:
        rate = f"{self.config.rate_hz:g} fps" if self.config.rate_hz else "recorded timing"
        extra = (", looping" if self.config.loop else "") + (", lossless" if self.lossless else "")
        return f"replay of {self.config.path} ({len(self._frames)} frames, {rate}{extra})"

    def open(self) -> None:
        try:
            sessions = find_sessions(self.config.path)
        except FileFormatError as exc:
            raise SourceError(f"replay: {exc}") from exc
        frames = [f for s in sessions for f in s.frames()]
        if not frames:
            raise SourceError(f"replay: {self.config.path}: no frames (expected frames/NNNNNN_left.png)")
        calib = sessions[0].calibration() if sessions[0].calibration_path.exists() else None
        for s in sessions[1:]:
            if s.calibration_path.exists() and s.calibration() != calib:
                raise SourceError(f"replay: {s.path} has a different calibration from {sessions[0].path}; "
                                  "replay one camera's sessions at a time")
        self.calibration = calib
        self._frames = frames
        self._times = self._timing(frames)
        self._i = 0
        self._lap = 0
        self._t0 = None       # pacing starts at the first read: start-up work after open() (the
                              # parameters' test render) must not make the first frames late

    def _timing(self, frames: list[FrameRecord]) -> list[float]:
        if self.config.rate_hz is None:
            stamps = [_recorded_time(f) for f in frames]
            if all(isinstance(t, (int, float)) for t in stamps) and list(stamps) == sorted(stamps):
                return [float(t) - float(stamps[0]) for t in stamps]
        rate = self.config.rate_hz or DEFAULT_RATE_HZ
        return [i / rate for i in range(len(frames))]

    def close(self) -> None:
        pass

    def read(self, timeout_s: float) -> Frame | None:
        if not self._frames:
            raise SourceError("replay: read() before open()")
        if self._i >= len(self._frames):
            if not self.config.loop:
                raise EndOfStream(f"replay: {self.config.path}: all {len(self._frames)} frames delivered")
            self._i = 0
            self._lap += 1
        lap_s = self._times[-1] + (self._times[1] - self._times[0] if len(self._times) > 1 else 0.1)
        if self._t0 is None:
            self._t0 = self.clock()
        due = self._t0 + self._lap * lap_s + self._times[self._i]
        wait = due - self.clock()
        if wait > timeout_s:
            self._stop.wait(timeout_s)
            return None
        if wait > 0 and self._stop.wait(wait):
            return None
        record = self._frames[self._i]
        self._i += 1
        try:
            left, right = record.load_pair()
            meta = record.load_meta()
        except FileFormatError as exc:   # one bad file in a log is skipped, not a lost camera
            log.warning("replay: skipping %s: %s", record.key, exc)
            return None
        truth = meta.get("branch_distance_m")
        return Frame(left=left, right=right, index=self._lap * len(self._frames) + self._i - 1,
                     t_capture=self.clock(), truth_m=float(truth) if isinstance(truth, (int, float)) else None,
                     meta={"replay_of": record.key})
