"""One frame's ranging result, and the reason codes of the outcomes that carry no distance."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Reason(enum.Enum):
    """Why a frame has no distance, or is too close: one code per rule (docs/ranging.md).

    The value is the rule in a few words, the same for every frame (what benchmarks
    count by); :attr:`Measurement.reason` says it with the frame's own numbers. The
    too-close rules are numbered as on docs/ranging.md, *Too close*.
    """

    #: Rule 1: the near pass matches a share of the region beyond the main search.
    NEAR_PASS = "the near pass matches the region beyond the search"
    #: Rule 3: the near pass matches beyond the search where the main pass matches nothing confidently.
    NEAR_UNCONFIRMED = "the near pass matches beyond the search where the main pass matches nothing"
    #: Rule 4: textured in both views, matched by neither pass.
    BLANK_TEXTURED = "textured in both views, matched by neither pass"
    #: Rule 5: a blank frame right after a too-close one (:meth:`~.gate.OutlierGate.near`).
    BLANK_AFTER_TOO_CLOSE = "blank after a too-close frame"
    #: Rule 2: the nearest object piles at the search's end.
    SEARCH_END = "the nearest object is at the search's end"
    #: Rule 6: the thin guard's object reads within the too-close factor of the search's end, or at its end.
    THIN_GUARD_TOO_CLOSE = "thin guard: too close"
    #: Rule 7: below the quality floor, reading within the too-close factor of the search's end.
    WEAK_NEAR = "below min_quality, within the too-close factor of the search's end"
    #: Rule 8: the reading lies in the search's last NEAR_END_BAND, inside the minimum range stated.
    NEAR_END_BAND = "in the search's last band, nearer than the minimum range"
    #: No significant object among the confident measured pixels.
    NO_OBJECT = "no significant object"
    #: A too-close rule fired, but the region holds no texture above the sensor noise: a featureless surface
    #: (sky, a bare wall) whose matches are the noise's (:func:`~.too_close.noise_floor`).
    FEATURELESS = "too-close evidence on a featureless region: sensor noise"
    #: The signal quality is below ``min_quality``.
    QUALITY_FLOOR = "signal quality below min_quality"
    #: The reading's sigma, taken at the object's median depth (its body), is above ``max_sigma_m``.
    SIGMA_CEILING = "sigma above max_sigma_m"
    #: The thin guard's nearer object is not precise enough to send, judged as the reading is (nor is the farther
    #: reading it replaces).
    THIN_GUARD_SIGMA = "thin guard: a nearer object, sigma above max_sigma_m"

    @property
    def too_close(self) -> bool:
        """The outcome says an object is nearer than the minimum range (no distance, never clear)."""
        return self in _TOO_CLOSE


_TOO_CLOSE = frozenset({Reason.NEAR_PASS, Reason.NEAR_UNCONFIRMED, Reason.BLANK_TEXTURED, Reason.BLANK_AFTER_TOO_CLOSE,
                        Reason.SEARCH_END, Reason.THIN_GUARD_TOO_CLOSE, Reason.WEAK_NEAR, Reason.NEAR_END_BAND})


@dataclass(frozen=True)
class Measurement:
    """One frame's ranging result. ``distance_m`` is None when there is no measurement (``reason_code`` says
    why, ``reason`` says it with the frame's numbers).

    ``sigma_m``: 1-sigma uncertainty of the distance; ``quality``: 2..100 from the
    valid fraction of the ROI and the object's mean confidence (1 is reserved for
    "invalid" on the wire); ``bbox``: (x0, y0, x1, y1) px of the object's pixels in
    the image; ``disparity_px``/``sigma_px``: the object's disparity and spread;
    ``n_px``: its pixel count; ``valid_fraction``: measured confident pixels / ROI area;
    ``too_close``: an object is nearer than the minimum range (``distance_m`` is then
    None: no distance was measured, but the obstacle is nearer than ``min_distance_m``);
    ``refined``: the distance, sigma, box and disparity come from the fine pass; ``guarded``: from the
    thin guard (``ranging.thin_guard_m2``), or it found the object too close; ``body_px``: the object's
    median disparity (input px), its body, which ``disparity_px`` leaves ``surface_quantile`` of nearer.
    """

    distance_m: float | None
    sigma_m: float | None = None
    quality: int = 0
    bbox: tuple[int, int, int, int] | None = None
    disparity_px: float | None = None
    sigma_px: float | None = None
    n_px: int = 0
    valid_fraction: float = 0.0
    reason: str | None = None
    too_close: bool = False
    refined: bool = False
    guarded: bool = False
    reason_code: Reason | None = None
    body_px: float | None = None

    @property
    def valid(self) -> bool:
        return self.distance_m is not None
