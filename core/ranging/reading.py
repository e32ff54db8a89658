"""The reading stages: the nearest significant object among the confident pixels, and its distance."""

from __future__ import annotations

from uav_depth.core.ranging.frame import RangingFrame
from uav_depth.core.ranging.measurement import Measurement, Reason
from uav_depth.core.ranging.nearest import find, reading
from uav_depth.core.ranging.setup import Setup


def nearest_object(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: the nearest significant object (:func:`.nearest.find`); no measurement when there is none."""
    f.obj = find(s, f.disp, f.conf, f.ok, s.px)
    if f.obj is None:
        cfg = s.config
        return Measurement(None, n_px=f.n_valid, valid_fraction=f.valid_fraction,
                           reason=f"no object of {cfg.min_valid_px} matched pixels and "
                                  f"{cfg.min_object_m2 * 1e4:g} cm^2 among the {f.n_valid} confident "
                                  f"measured pixels in the ROI", reason_code=Reason.NO_OBJECT)
    return None


def read(s: Setup, f: RangingFrame) -> Measurement | None:
    """Stage: the object's distance (:func:`.nearest.reading`); decides nothing."""
    assert f.obj is not None and f.bbox is not None
    f.reading = reading(s, f.obj, f.bbox, f.quality, f.valid_fraction)
    return None
