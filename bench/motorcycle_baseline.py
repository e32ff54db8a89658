"""Manual baseline on scikit-image's Middlebury 2014 motorcycle pair: prints the metrics."""

import time

import cv2
import numpy as np
from skimage import data

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.params import DEFAULT_PARAMS
from uav_depth.tuning.metrics import score

left, right, gt = data.stereo_motorcycle()
left, right = cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR)
pipe = DisparityPipeline(DEFAULT_PARAMS)
times = []
for _ in range(5):
    t0 = time.perf_counter()
    disp = pipe.compute(left, right)
    times.append(time.perf_counter() - t0)
s = score(gt, disp)
print(f"motorcycle 741x500 manual baseline: mse {s.mse:.1f} psnr {s.psnr:.2f} ssim {s.ssim:.3f} "
      f"bad1 {s.bad1:.1f}% bad2 {s.bad2:.1f}% valid {s.valid:.3f} median {np.median(times) * 1000:.0f} ms")
