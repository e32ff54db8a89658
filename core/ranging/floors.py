"""The floors a reading must pass to be sent: its signal quality (``min_quality``) and its precision
(``max_sigma_m``)."""

from __future__ import annotations

from dataclasses import replace

from uav_depth.core.ranging.frame import RangingFrame
from uav_depth.core.ranging.limits import WEAK_TOO_CLOSE_FACTOR
from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.nearest import shift
from uav_depth.core.ranging.setup import Setup


def quality_floor(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: the object's signal quality, 2..100 from the valid fraction of the ROI and its mean confidence
    (1 is "invalid" on the wire); below ``min_quality`` no measurement, or too close when the object reads
    within :data:`~.limits.WEAK_TOO_CLOSE_FACTOR` x the search's end (rule 7: a twig inside the minimum range
    matched weakly just beyond it). Wrong readings scored 2-30, correct ones 39-85 (docs/ranging.md,
    *Quality floor*)."""
    cfg, obj = s.config, f.obj
    assert obj is not None
    x0, y0, _, _ = s.roi
    f.quality = int(min(100, max(2, round(100.0 * f.valid_fraction * obj.mean_conf))))
    f.bbox = shift(obj.bbox, x0, y0)
    if f.quality >= cfg.min_quality:
        return None
    z, lim = s.fb / obj.d, s.search_end_m
    weak_near = z < WEAK_TOO_CLOSE_FACTOR * lim
    why = (f"and the nearest object reads {z:.3f} m, within {WEAK_TOO_CLOSE_FACTOR:g} x the search's end "
           f"{lim:.3f} m: too close" if weak_near else f"(the object would read {z:.3f} m)")
    return Measurement(None, quality=f.quality, bbox=f.bbox, disparity_px=obj.d, sigma_px=obj.sigma_d,
                       n_px=obj.n, valid_fraction=f.valid_fraction, too_close=weak_near,
                       reason=f"signal quality {f.quality} below min_quality {cfg.min_quality} {why}",
                       reason_code=Reason.WEAK_NEAR if weak_near else Reason.QUALITY_FLOOR)


def sigma_ceiling(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: a reading less precise than ``max_sigma_m`` (by default the most DISTANCE_SENSOR's covariance can
    carry), judged at the object's body (:func:`imprecise`), is no measurement."""
    m = f.reading
    assert m is not None and m.sigma_m is not None and m.distance_m is not None
    why = imprecise(s, m)
    if why is not None:
        return replace(m, distance_m=None, sigma_m=None, refined=False, reason=why, reason_code=Reason.SIGMA_CEILING)
    return None


def imprecise(s: Setup, m: Measurement) -> str | None:
    """Why the reading ``m`` is too imprecise to send (``ranging.max_sigma_m``), or None: the one precision rule,
    for the confident reading and the thin guard's.

    The precision is judged at the object's body, its median disparity (``m.body_px``), not at the reading,
    which leaves ``surface_quantile`` of the object nearer: toward the range's end that share is the near tail
    of the matching noise (the fine pass locks part of a level branch's pixels up to a whole pixel nearer, and
    its band, a fraction of a pixel deep there, holds little else), so judged at the reading a branch beyond
    the range went out whenever its tail read inside it, 10-55 cm near (docs/ranging.md, *The nearest
    significant object*). The sigma sent stays the reading's own.
    """
    assert m.distance_m is not None and m.disparity_px is not None and m.sigma_px is not None
    body = m.disparity_px if m.body_px is None else min(m.body_px, m.disparity_px)
    z_body = s.fb / body
    sigma_body = z_body * z_body / s.fb * m.sigma_px
    if sigma_body <= s.config.max_sigma_m:
        return None
    return (f"sigma {sigma_body:.3f} m at the object's median depth {z_body:.3f} m above max_sigma_m "
            f"{s.config.max_sigma_m:.3f} m (the object would read {m.distance_m:.3f} m)")
