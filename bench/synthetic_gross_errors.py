"""Gross ranging errors on varied synthetic 1280x720 scenes with the flight parameters (30 scenes, seed 11).

Run: .venv/bin/python bench/synthetic_gross_errors.py
"""
import numpy as np
from uav_depth.core.params.flight import flight_params
from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.ranging import Ranger, default_roi, RangingConfig
from uav_depth.sim.scene import Scene, SceneConfig, vary
fp = flight_params(); pipe = DisparityPipeline(fp)
rng = np.random.default_rng(11); base = SceneConfig()
errs=[]
for i in range(30):
    cfg = vary(base, rng)
    f = Scene(cfg).render(rng=rng); truth = f.nearest_branch_distance(cfg.center_roi)
    m = Ranger(RangingConfig(), cfg.calibration, default_roi(1280,720), fp).measure(pipe.run(f.left,f.right))
    errs.append(abs(m.distance_m-truth)/truth*100 if m.valid else np.nan)
e=np.array(errs); print('median %.2f%%, gross(>10%%) %d/30, invalid %d, >2%% %d' % (np.nanmedian(e),(e>10).sum(),np.isnan(e).sum(),(e>2).sum()))
rng = np.random.default_rng(11)
