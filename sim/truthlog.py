"""What a SITL run rendered, beside the ground truth: the poses each frame was rendered from, and a CSV.

:class:`PoseRecorder` wraps the :class:`~uav_depth.sim.sitl.PoseTracker` as the
synthetic source's pose provider and remembers which vehicle state each rendered pose
came from; :class:`TruthLog` writes every processed frame of a running service as one
CSV row (pose, truth, measurement), so a run can be scored afterwards.
"""

from __future__ import annotations

import collections
import csv
import logging
import math
import statistics
import threading
from pathlib import Path
from typing import Any

import numpy as np

from uav_depth.sim.scene import Pose
from uav_depth.sim.sitl import PoseTracker, VehicleState

log = logging.getLogger("uav_depth.sitl")


class PoseRecorder:
    """The tracker as a pose provider that remembers which vehicle state each rendered pose came from."""

    def __init__(self, tracker: PoseTracker, keep: int = 512):
        self.tracker = tracker
        self._log: collections.deque[tuple[float, VehicleState]] = collections.deque(maxlen=keep)
        self._lock = threading.Lock()

    @property
    def pose_time(self) -> float | None:
        return self.tracker.pose_time

    @property
    def predicts(self) -> bool:
        return self.tracker.predicts

    def __call__(self, t_s: float = 0.0, at: float | None = None) -> Pose:
        pose = self.tracker(t_s, at)
        state = self.tracker.pose_state
        if state is not None:
            with self._lock:   # keyed by the pose's own time: the frame's capture time
                self._log.append((state.t, state))
        return pose

    def state_at(self, t: float, within_s: float = 0.1) -> VehicleState | None:
        """The state rendered closest to monotonic time ``t`` (None if none within ``within_s``)."""
        with self._lock:
            entries = list(self._log)
        if not entries:
            return None
        t_best, state = min(entries, key=lambda e: abs(e[0] - t))
        return state if abs(t_best - t) <= within_s else None


CSV_COLUMNS = ("time_s", "frame", "north_m", "east_m", "down_m", "roll_deg", "pitch_deg", "yaw_deg",
               "truth_m", "measured_m", "sigma_m", "quality", "error_pct", "latency_ms", "reason", "monotonic_s")


class TruthLog:
    """Every processed frame of a running service as one CSV row: pose, truth, measurement.

    Polls ``service.last_estimate`` on a thread of its own (never in the frame loop).
    ``error_pct`` = 100 (measured - truth) / truth. ``monotonic_s``: the capture time
    on the system-wide monotonic clock (CLOCK_MONOTONIC), so another process on the
    same machine (a SITL harness) can line rows up with what it saw. Rows are
    flushed as written, so a killed run keeps what it logged.
    """

    def __init__(self, path: str | Path, service: Any, recorder: PoseRecorder | None = None,
                 tree_ned: np.ndarray | None = None, poll_s: float = 0.01):
        self.path = Path(path)
        self.service = service
        self.recorder = recorder
        self.tree_ned = tree_ned
        self.poll_s = poll_s
        self.errors_pct: list[float] = []
        self.rows = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._file: Any = None

    def start(self) -> "TruthLog":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("w", newline="", buffering=1)
        self._writer = csv.writer(self._file)
        self._writer.writerow(CSV_COLUMNS)
        self._thread = threading.Thread(target=self._loop, name="sitl-truth", daemon=True)
        self._thread.start()
        where = "" if self.tree_ned is None else " (tree at NED %s m)" % [round(float(v), 3) for v in self.tree_ned]
        log.info("logging ground truth beside each measurement to %s%s", self.path, where)
        return self

    def _loop(self) -> None:
        last = None
        while not self._stop.wait(self.poll_s):
            est = self.service.last_estimate
            if est is None or est.frame_index == last:
                continue
            last = est.frame_index
            self._row(est)

    def _row(self, est: Any) -> None:
        m = est.measurement
        state = self.recorder.state_at(est.t_capture) if self.recorder is not None else None
        err = None
        if m.valid and est.truth_m:
            err = 100.0 * (m.distance_m - est.truth_m) / est.truth_m
            self.errors_pct.append(err)
        def f(v: float | None, nd: int = 4) -> str:
            return "" if v is None else f"{v:.{nd}f}"
        pose = ([f(v) for v in state.position_ned] + [f(math.degrees(a), 2) for a in (state.roll, state.pitch,
                                                                                       state.yaw)]
                if state is not None else [""] * 6)
        self._writer.writerow([f(est.t_capture - self.service.t0, 3), est.frame_index, *pose, f(est.truth_m),
                               f(m.distance_m), f(m.sigma_m), m.quality, f(err, 2),
                               f(est.timings_ms.get("latency"), 1), m.reason or "", f(est.t_capture, 3)])
        self.rows += 1

    def close(self, timeout_s: float = 1.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._file is not None:
            self._file.close()
            self._file = None

    def summary(self) -> str:
        errs = [abs(e) for e in self.errors_pct]
        if not errs:
            return f"{self.rows} frames, none measured"
        errs.sort()
        p95 = errs[min(len(errs) - 1, int(math.ceil(0.95 * len(errs))) - 1)]
        return (f"{self.rows} frames, {len(errs)} measured; |error| median {statistics.median(errs):.2f} %, "
                f"95th percentile {p95:.2f} %, max {errs[-1]:.2f} %")
