"""Branch-distance error of the ranging statistic (surface_quantile) on synthetic 1280x720 scenes, flight parameters.

Run: .venv/bin/python bench/ranging_quantile.py
"""
import numpy as np
from dataclasses import replace
from uav_depth.cli.benchmark import make_frames
from uav_depth.core.params.flight import flight_params
from uav_depth.core.disparity import DisparityPipeline, DisparityResult
from uav_depth.core.ranging import Ranger, default_roi, RangingConfig
frames = make_frames(24, seed=5)
fp = flight_params()
pipe = DisparityPipeline(fp)
res = [pipe.run(f.left, f.right) for f in frames]
for q in (0.5, 0.3, 0.2, 0.1):
    errs=[]; exact=[]
    for f, r in zip(frames, res):
        h,w=f.left.shape[:2]
        rg = Ranger(replace(RangingConfig(), surface_quantile=q), f.scene.calibration, default_roi(w,h), fp)
        m = rg.measure(r)
        errs.append(abs(m.distance_m-f.truth_m)/f.truth_m*100 if m.valid else np.nan)
        ex = DisparityResult(f.disparity, f.disparity, np.ones_like(f.disparity))
        m2 = Ranger(replace(RangingConfig(), surface_quantile=q), f.scene.calibration, default_roi(w,h), fp).measure(ex)
        exact.append(abs(m2.distance_m-f.truth_m)/f.truth_m*100)
    e=np.array(errs); x=np.array(exact)
    print(q, 'pipeline median %.2f%% p90 %.2f%% max %.2f%% n>2%%: %d | exact-disp median %.2f max %.2f' % (np.nanmedian(e), np.nanpercentile(e,90), np.nanmax(e), (e>2).sum(), np.median(x), x.max()))
