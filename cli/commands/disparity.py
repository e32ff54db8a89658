"""uav-depth disparity LEFT RIGHT --out FILE.

A pair the parameters cannot match (narrower than the disparity search plus the block) is
refused with the rule it breaks and exit 78, as the daemon refuses such parameters at load,
instead of an all-invalid map that says nothing of why.
"""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("left", help="left image (rectified)")
    p.add_argument("right", help="right image (rectified)")
    p.add_argument("--params", help="parameter file (default: built-in manual baseline)")
    p.add_argument("--out", required=True, help="output: .npy (float32 px, NaN invalid), .pfm, or .png (coloured)")


def run(args: argparse.Namespace) -> int:
    import time

    import cv2
    import numpy as np

    from uav_depth.core.disparity import DisparityPipeline
    from uav_depth.core.errors import FileFormatError
    from uav_depth.core.params import DEFAULT_PARAMS, check_image_size, load_params
    from uav_depth.core.session import write_disparity

    params = load_params(args.params) if args.params else DEFAULT_PARAMS
    imgs = []
    for path in (args.left, args.right):
        img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise FileFormatError(f"{path}: missing or not a readable image")
        imgs.append(img)
    height, width = imgs[0].shape[:2]
    check_image_size(params, width, height, f"{args.params or 'built-in manual baseline'} on {args.left} "
                                            f"({width}x{height} px)")
    t0 = time.perf_counter()
    disp = DisparityPipeline(params).compute(*imgs)
    ms = (time.perf_counter() - t0) * 1000
    write_disparity(args.out, disp)
    print(f"{args.out}: {np.isfinite(disp).mean() * 100:.1f}% valid, {ms:.0f} ms")
    return 0
