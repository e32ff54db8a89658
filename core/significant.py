"""What counts as an object: the one definition shared by ranging and the simulator's ground truth.

A significant object is one the pruning tool or the airframe would hit and be
hurt by, defined in metres so the rule holds at any range and ``compute.scale``:
at least :data:`SIGNIFICANT_WIDTH_M` thick (a twig of 3-10 mm deflects the saw and
snags a propeller; a 1 mm pine needle is cut through or bent aside) and showing at
least :data:`SIGNIFICANT_AREA_M2` of visible surface in the region (a pixel at
depth Z covers (Z / f)^2 m^2, i.e. (B / d)^2 at disparity d).
"""

from __future__ import annotations

SIGNIFICANT_WIDTH_M = 0.003
SIGNIFICANT_AREA_M2 = 2e-4


def pixel_area_m2(disparity_px: float, baseline_m: float) -> float:
    """Visible area one input pixel covers at ``disparity_px``: (Z / f)^2 = (B / d)^2, m^2."""
    return (baseline_m / disparity_px) ** 2
