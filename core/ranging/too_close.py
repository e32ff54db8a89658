"""Too close: an object nearer than the minimum range is reported as such, never as a farther distance.

The rules are numbered as on docs/ranging.md, *Too close*. Here: the near check's
evidence (rules 1, 3 and 4, from the near pass of :mod:`uav_depth.core.disparity.near`),
an object piled at the search's end (rule 2) and a reading in the search's last
:data:`~.limits.NEAR_END_BAND` (rule 8). Rule 5 is the outlier gate's
(:meth:`.gate.OutlierGate.near`), rule 6 the thin guard's (:mod:`.thin_guard`), rule 7
the quality floor's (:mod:`.floors`). Over every rule but 5 (whose evidence is the too-close frame before),
the noise floor (:func:`noise_floor`): a too-close outcome on a region without texture above the sensor
noise is no measurement.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from uav_depth.core.disparity import DisparityResult
from uav_depth.core.ranging.frame import RangingFrame
from uav_depth.core.ranging.limits import NEAR_END_BAND
from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.nearest import CLUSTER_MARGIN_PX
from uav_depth.core.ranging.setup import Setup
from uav_depth.core.ranging.stats import share_of

#: Rule 1: at least this share of the ROI matched beyond the main search by the near pass, left-right consistent.
#: With the flight file, branches at 0.08-0.27 m give 0.21-0.74 and frames with nothing nearer than the minimum
#: range at most 0.06 (docs/ranging.md, *Too close*, rule 1).
NEAR_BEYOND_SHARE = 0.15
#: Rule 3: ... or at least this share matched beyond the main search where the main pass has no confident match,
#: if those are at least NEAR_UNCONFIRMED_RATIO of the near pass's matches beyond it (a twig in front; false near
#: matches on a repeating background lie where the main pass matched confidently). Twigs 0.13-0.28 m away give
#: 3.4-14 % at ratios 0.83-0.99, frames with nothing inside the minimum range at most 0.9 % at a ratio above 0.75;
#: a 1.8 cm branch at 0.30 m gives 1.9 %. 1.5 % of the region is 2.4 cm^2 at the flight file's minimum range, over
#: a significant object's 2 cm^2 (docs/ranging.md, *Too close*, rule 3).
NEAR_UNCONFIRMED_SHARE = 0.015
NEAR_UNCONFIRMED_RATIO = 0.75
#: Rules 4 and 5: a frame that matches under this share of the ROI is blank. Every frame with something in range
#: matched at least 14 % of its ROI (docs/ranging.md, *Too close*, rules 4 and 5).
BLANK_VALID_FRACTION = 0.1
#: Rule 4: ... and a blank frame is too close while at least this share of the ROI is textured in both views
#: (:func:`uav_depth.core.disparity.near.textured`): nearer than the near pass can see (a few cm), the object's
#: other view lies outside the right image. Such frames are 1.8-53 % textured and 0-7 % matched
#: (docs/ranging.md, *Too close*, rule 4).
TEXTURED_SHARE = 0.01
#: Every rule: a frame is too close only while at least this share of the ROI is textured in the left view
#: (:func:`uav_depth.core.disparity.near.left_textured`, the same gradient as rule 4's). On a featureless
#: surface SGBM matches the sensor noise, left-right consistent, anywhere in the search: a blank scene with noise
#: of 1-8 grey levels fired rules 1, 3 and 6, and is 0-0.5 % textured; every frame of a branch inside the minimum
#: range is 12-88 % (docs/ranging.md, *Too close*, noise floor).
SIGNAL_SHARE = TEXTURED_SHARE


def near_evidence(s: Setup, result: DisparityResult, usable_share: float = 0.0) -> tuple[Reason, str] | None:
    """Why the region holds an object nearer than the minimum range by the near check (rules 1, 3, 4), or None.
    ``usable_share``: the share of the ROI ranging's usable pixels make (:func:`.nearest.usable`), when known."""
    near = result.near
    if near is None:
        return None
    x0, y0, x1, y1 = s.roi
    cfg = s.config
    nd = near.disparity[y0:y1, x0:x1]
    with np.errstate(invalid="ignore"):
        # Rules 1 and 3 on the near pass's left-right check alone: at its coarse scale a branch a few pixels
        # wide is all depth edge, and the confidence's roll-off weighs it 0 (docs/ranging.md, rule 1).
        beyond = nd > s.d_max       # NaN compares False: only where the near pass matched
        if near.consistent is not None:
            beyond &= near.consistent[y0:y1, x0:x1]
    share = share_of(beyond) if beyond.size else 0.0
    if share >= NEAR_BEYOND_SHARE:
        b = nd[beyond]
        return Reason.NEAR_PASS, (f"the near pass matches {share:.0%} of the ROI at disparities {np.median(b):.0f} "
                                  f"px (median), beyond the search's {s.d_max:.0f} px: nearer than "
                                  f"{s.limits.min_distance_m:.3f} m")
    main = None

    def main_matched() -> np.ndarray:
        # The main pass's confident matches at any disparity it searches (the far floor does not apply).
        with np.errstate(invalid="ignore"):
            m = np.isfinite(result.measured[y0:y1, x0:x1])
            if result.confidence is not None:
                m &= result.confidence[y0:y1, x0:x1] >= cfg.min_confidence
        return m

    if share >= NEAR_UNCONFIRMED_SHARE:
        # A smaller near object (a twig in front): the near pass's matches beyond the search where the main
        # pass has no confident match of its own (where it has one, the near match is the false one).
        main = main_matched()
        unconfirmed = beyond & ~main
        u_share = share_of(unconfirmed)
        if u_share >= NEAR_UNCONFIRMED_SHARE and unconfirmed.sum() >= NEAR_UNCONFIRMED_RATIO * beyond.sum():
            b = nd[unconfirmed]
            return Reason.NEAR_UNCONFIRMED, (
                f"the near pass matches {u_share:.1%} of the ROI at disparities {np.median(b):.0f} px "
                f"(median), beyond the search's {s.d_max:.0f} px, where the main pass matches nothing "
                f"confidently: nearer than {s.limits.min_distance_m:.3f} m")
    if near.textured is None:
        return None
    # Rule 4 on the near pass's confident matches (docs/ranging.md, rule 1 says why not its left-right check).
    # The main pass's alone first: when they already pass, so does the union, and the near pass's confidence
    # (computed when asked for) is not needed.
    # The usable pixels are main matches (above the far floor): when they make the share, so does the main pass.
    if main is None and usable_share >= BLANK_VALID_FRACTION:
        return None
    main = main_matched() if main is None else main
    if share_of(main) >= BLANK_VALID_FRACTION:
        return None
    near_ok = np.isfinite(nd)
    if near.confidence is not None:
        near_ok &= near.confidence()[y0:y1, x0:x1] >= cfg.min_confidence
    matched = near_ok | main
    m_all = share_of(matched)
    if m_all >= BLANK_VALID_FRACTION:
        return None
    # Blank: is it textured (an object nearer than either search) or not (sky, a bare wall)?
    tex = near.textured()[y0:y1, x0:x1]
    tex_share = share_of(tex) if tex.size else 0.0
    if tex_share >= TEXTURED_SHARE and share_of(matched[tex]) < BLANK_VALID_FRACTION:
        return Reason.BLANK_TEXTURED, (
            f"{tex_share:.0%} of the ROI is textured in both views but neither pass matches it at any "
            f"disparity it searches ({m_all:.0%} of the ROI matched): an object nearer than either search "
            f"fills the view, nearer than {s.limits.min_distance_m:.3f} m")
    return None


def near_check(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: too close by the near check's evidence (rules 1, 3, 4)."""
    evidence = near_evidence(s, f.result, f.valid_fraction)
    if evidence is None:
        return None
    code, why = evidence
    return Measurement(None, n_px=f.n_valid, valid_fraction=f.valid_fraction, reason=why, too_close=True,
                       reason_code=code)


def at_search_end(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: too close when the nearest object piles at the end of the search (rule 2): it may be nearer than
    SGBM can tell."""
    assert f.obj is not None
    if f.obj.front >= s.d_max - CLUSTER_MARGIN_PX * s.px:
        return Measurement(None, n_px=f.n_valid, valid_fraction=f.valid_fraction, too_close=True,
                           reason=f"the nearest object's disparity {f.obj.front:.1f} px is at the search's end "
                                  f"{s.d_max:.1f} px: nearer than {s.limits.min_distance_m:.3f} m",
                           reason_code=Reason.SEARCH_END)
    return None


def near_end_band(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: too close when the reading that would go out (the fine one when it stands) lies in the search's last
    :data:`~.limits.NEAR_END_BAND` (rule 8)."""
    m = f.reading
    assert m is not None and m.distance_m is not None
    if m.distance_m < s.limits.min_distance_m:
        return replace(m, distance_m=None, sigma_m=None, refined=False, too_close=True,
                       reason=f"the nearest object reads {m.distance_m:.3f} m, in the search's last "
                              f"{NEAR_END_BAND * 100:g} % (where an object nearer than the search is matched "
                              f"falsely): nearer than the minimum range {s.limits.min_distance_m:.3f} m",
                       reason_code=Reason.NEAR_END_BAND)
    return None


def noise_floor(s: Setup, m: Measurement, result: DisparityResult) -> Measurement:
    """Check: ``m``, or no measurement when it is too close but under :data:`SIGNAL_SHARE` of the ROI is textured
    in the left view: no rule's evidence survives the sensor noise (the region is featureless, so its matches
    are the noise's). Asks for the texture map only on a too-close frame; without one, ``m``."""
    near = result.near
    if not m.too_close or near is None or near.left_textured is None:
        return m
    x0, y0, x1, y1 = s.roi
    share = float(near.left_textured()[y0:y1, x0:x1].mean())
    if share >= SIGNAL_SHARE:
        return m
    return Measurement(None, n_px=m.n_px, valid_fraction=m.valid_fraction, reason_code=Reason.FEATURELESS,
                       reason=f"{share:.1%} of the ROI is textured in the left view, under {SIGNAL_SHARE:.0%}: the "
                              f"evidence for too close ({m.reason}) is the sensor noise of a featureless surface")
