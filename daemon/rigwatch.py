"""The rig check in flight: every ``rig_check.interval_s`` the newest rectified pair is checked
(:func:`uav_depth.core.rigcheck.check_rig`) on a thread of its own, the figure is logged, and a
warning (log line and STATUSTEXT) is raised when the misalignment passes ``rig_check.threshold_px``.

The stereo loop only hands over references to the pair (one assignment); a check takes about
a second of one core at 640x360, on a thread niced to 19, so the default period is a minute.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from uav_depth.core.errors import FrameError
from uav_depth.core.keys import Key
from uav_depth.core.rigcheck import MAX_VERTICAL_PX, RigCheck, check_rig
from uav_depth.daemon.worker import NicedWorker

log = logging.getLogger("uav_depth.rigcheck")


@dataclass(frozen=True)
class RigCheckConfig:
    """The ``rig_check:`` section of the run config."""

    interval_s: float = 60.0
    threshold_px: float = MAX_VERTICAL_PX

    KEYS = (
        Key("interval_s", "float", 60.0, "period of the in-flight rig check (vertical misalignment of the "
            "rectified pair, logged); 0 disables it", 0.0, 86400.0),
        Key("threshold_px", "float", MAX_VERTICAL_PX, "vertical misalignment that raises a warning, px "
            "(SGBM degrades past 0.5 px: docs/rigcheck.md)", 0.05, 10.0),
    )


class RigWatch(NicedWorker):
    """Checks the newest pair every ``interval_s`` until ``stop`` is set. ``warn``: STATUSTEXT sender."""

    NAME = "rig-check"
    NICENESS = 19

    def __init__(self, config: RigCheckConfig, warn: Callable[[str], object]):
        self.config = config
        self.warn = warn
        self._pair: tuple[np.ndarray, np.ndarray] | None = None
        self.last: RigCheck | None = None
        self._misaligned = False

    def offer(self, left: np.ndarray, right: np.ndarray) -> None:
        self._pair = (left, right)


    def check_now(self) -> RigCheck | None:
        pair = self._pair
        if pair is None:
            return None
        try:
            check = check_rig(pair[0], pair[1], self.config.threshold_px)
        except FrameError as exc:
            log.warning("rig check skipped: %s", exc)
            return None
        self.last = check
        if check.ok is False:
            log.warning("rig check: %s", check.verdict())
            if not self._misaligned:
                self.warn(f"uav-depth: rig misaligned {check.vertical_worst_px:.1f}px")
            self._misaligned = True
        else:
            log.info("rig check: %s", check.verdict())
            if check.ok:
                self._misaligned = False
        return check

    def _loop(self, stop: threading.Event) -> None:
        while not stop.wait(self.config.interval_s):
            try:
                self.check_now()
            except Exception:   # the check must never take the daemon down
                log.exception("rig check failed")
