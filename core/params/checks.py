"""Parameter rules that depend on more than one key or on the image: what OpenCV can compute, and a search range
for a camera."""

from __future__ import annotations

import math

from uav_depth.core.errors import ConfigError
from uav_depth.core.params.schema import COMPUTABLE_MAX, SPEC_BY_KEY, StereoParams


def disparity_search_range(focal_px: float, baseline_m: float, near_m: float, far_m: float = math.inf,
                           scale: float = 1.0) -> tuple[int, int]:
    """``(sgbm.min_disparity, sgbm.num_disparities)`` covering distances ``near_m``..``far_m``.

    d = f * B / Z in input pixels, times ``compute.scale`` because SGBM counts
    matched pixels. ``far_m`` infinite (the default) keeps min_disparity 0, so the
    far background still finds its true match instead of a false near one. The
    values are checked against the schema like any file value.
    """
    if not (math.isfinite(near_m) and near_m > 0):
        raise ConfigError("near_m", "must be a positive distance in metres", near_m)
    if not far_m > near_m:
        raise ConfigError("far_m", f"must be greater than near_m ({near_m})", far_m)
    fb = focal_px * baseline_m * scale
    min_d = int(math.floor(fb / far_m)) if math.isfinite(far_m) else 0
    max_d = int(math.ceil(fb / near_m))
    num = 16 * math.ceil((max_d - min_d + 1) / 16)
    return (SPEC_BY_KEY["sgbm.min_disparity"].check(min_d, "disparity_search_range"),
            SPEC_BY_KEY["sgbm.num_disparities"].check(num, "disparity_search_range"))


def check_computable(params: StereoParams, source: str | None = None) -> StereoParams:
    """Refuse parameters OpenCV cannot compute with, whatever the image: penalties over its 16-bit cost range.

    The schema's bounds for p1/p2 are the paper's search ranges (the faithful tuner
    explores them, and the pipeline answers an overflow with an all-NaN map); a file
    the daemon flies or ``params check`` passes must also satisfy this.
    """
    for key, most in COMPUTABLE_MAX.items():
        value = params.get(key)
        if value > most:
            raise ConfigError(key, f"must be at most {most} (OpenCV's SGBM keeps costs in 16-bit "
                                   "integers; above it they wrap and nothing is measured)", value, source)
    return params


def check_image_size(params: StereoParams, width: int, height: int, source: str | None = None) -> None:
    """Refuse parameters that cannot match anything in a ``width`` x ``height`` input image.

    OpenCV's SGBM refuses an image whose matched width is not more than
    min_disparity + num_disparities + block_size // 2 (matched pixels, i.e. the input
    times ``compute.scale``), and computes a disparity only for columns x with
    min_disparity + num_disparities <= x; its block must fit the image.
    """
    sg, scale = params.sgbm, params.compute.scale
    mw, mh = int(round(width * scale)), int(round(height * scale))
    reach = sg.min_disparity + sg.num_disparities
    if mw - reach <= sg.block_size // 2:
        raise ConfigError("sgbm.num_disparities", f"must leave columns to match: sgbm.min_disparity + "
                          f"sgbm.num_disparities + sgbm.block_size // 2 must be below the matched image width "
                          f"{mw} px ({width} px x compute.scale {scale:g})", sg.num_disparities, source)
    if sg.block_size > min(mw, mh):
        raise ConfigError("sgbm.block_size", f"must fit the matched image ({mw}x{mh} px)", sg.block_size, source)
