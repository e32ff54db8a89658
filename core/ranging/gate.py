"""The outlier gate over successive readings: asymmetric, a nearer reading at once, a jump away confirmed."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.too_close import BLANK_VALID_FRACTION


@dataclass
class OutlierGate:
    """Single-frame outlier rejection over successive measurements, asymmetric.

    A nearer distance is accepted at once, whatever the jump: for a drone closing
    on a branch, a sudden nearer object must win now, and holding it back would
    keep sending the older, farther distance. A distance *farther* than the last
    accepted one by more than ``max_jump_rel`` (relative) is held back; it is
    accepted once ``confirm_frames`` consecutive frames agree with each other within
    that tolerance. After ``forget_s`` without an accepted measurement the history
    is forgotten (the next one is accepted). :meth:`too_close` records a frame
    reported too close as the nearest distance, so that a jump away from it needs
    confirming too.
    """

    max_jump_rel: float
    confirm_frames: int
    forget_s: float = 1.0
    _last: float | None = None
    _last_t: float = -math.inf
    _pending: list[float] = field(default_factory=list)
    _too_close_t: float = -math.inf

    def accept(self, distance_m: float, t: float) -> bool:
        if self.max_jump_rel <= 0 or self._last is None or t - self._last_t > self.forget_s:
            return self._take(distance_m, t)
        if distance_m - self._last <= self.max_jump_rel * self._last:     # nearer, or not much farther
            return self._take(distance_m, t)
        if self._pending and abs(distance_m - self._pending[-1]) > self.max_jump_rel * self._pending[-1]:
            self._pending = []
        self._pending.append(distance_m)
        if len(self._pending) >= self.confirm_frames:
            return self._take(distance_m, t)
        return False

    def too_close(self, min_distance_m: float, t: float) -> None:
        """A frame found the object nearer than ``min_distance_m``: the nearest possible reading."""
        self._take(min_distance_m, t)
        self._too_close_t = t

    def near(self, m: Measurement, min_distance_m: float, t: float) -> Measurement:
        """Book a too-close measurement; keep a blank frame right after one too close (rule 5).

        A frame that measures almost nothing (valid fraction under
        :data:`~.too_close.BLANK_VALID_FRACTION`) within ``forget_s`` of a too-close one is too
        close as well: the object that came nearer than the minimum range now fills
        the view and nothing in it can be matched (seen at 0.05-0.07 m).
        """
        if m.too_close:
            self.too_close(min_distance_m, t)
            return m
        if (not m.valid and m.valid_fraction < BLANK_VALID_FRACTION and t - self._too_close_t <= self.forget_s):
            self.too_close(min_distance_m, t)
            return replace(m, too_close=True, reason=f"blank after a too-close frame ({m.reason})",
                           reason_code=Reason.BLANK_AFTER_TOO_CLOSE)
        return m

    def _take(self, distance_m: float, t: float) -> bool:
        self._last, self._last_t, self._pending = distance_m, t, []
        return True

    def reset(self) -> None:
        self._last, self._last_t, self._pending, self._too_close_t = None, -math.inf, [], -math.inf
