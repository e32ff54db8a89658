"""What the parameters' first-use check (daemon.stage.test_render) costs, and what it refuses.

Builds the stage for a few parameter sets and image sizes and times one test
render each (the check runs once per parameter file, at start-up and on reload,
on the loading thread, never in the frame loop).

    .venv/bin/python bench/test_render_cost.py
"""

from __future__ import annotations

import time

from uav_depth.core.calibration import calibration_from_dict
from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.params import DEFAULT_PARAMS, load_params
from uav_depth.core.ranging import Ranger, RangingConfig, resolve_roi
from uav_depth.daemon.stage import Stage, test_render

CASES = [
    ("manual defaults", DEFAULT_PARAMS, 1280, 720, 700.0),
    ("deploy/params-flight.yaml", load_params("deploy/params-flight.yaml"), 1280, 720, 700.0),
    ("manual defaults", DEFAULT_PARAMS, 640, 360, 350.0),
    ("num_disparities 64", DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64}), 320, 240, 200.0),
    ("uniqueness_ratio 100", DEFAULT_PARAMS.replace(**{"sgbm.uniqueness_ratio": 100}), 640, 360, 350.0),
    ("num_disparities 1024, block 31", DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 1024,
                                                                 "sgbm.block_size": 31}), 1280, 720, 700.0),
]


def main() -> None:
    for name, params, w, h, f in CASES:
        calib = calibration_from_dict({"focal_px": f, "baseline_m": 0.063, "width": w, "height": h})
        roi = resolve_roi(None, w, h)
        stage = Stage(params, flight_pipeline(params), Ranger(RangingConfig(), calib, roi, params), name)
        t = time.monotonic()
        why, z = test_render(stage, w, h)
        ms = (time.monotonic() - t) * 1000
        print(f"{name:32s} {w}x{h}: {'measures' if why is None else 'REFUSED (' + why + ')'} at {z:.2f} m, "
              f"{ms:.0f} ms")


if __name__ == "__main__":
    main()
