"""Should ranging use the WLS output or the confident measured pixels? Same run, same Ranger, both ways.

For each parameter set (manual baseline, deploy/params-flight.yaml) the full
pipeline (WLS included) runs once per pair; the daemon's ``Ranger`` then ranges
``measured`` + ``confidence`` (what flies) and, in its place, the WLS map
``disparity`` with the same confidence. Real pairs: the 17 Middlebury 2006 pairs
(reference: the same ranging on the ground truth, as bench/real_ranging.py);
synthetic: plain branches (SceneConfig(seed, branch_distance_m=d,
branch_radius_m=0.03)) at 0.4-3.0 m, seeds 0-1.

    .venv/bin/python bench/wls_vs_measured.py --data ../shared/data/middlebury2006
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_ranging import DEFAULT_DATA, SCENES, calibration_for, load_scene  # noqa: E402

from uav_depth.cli.benchmark import machine_line  # noqa: E402
from uav_depth.core.disparity import FAITHFUL, DisparityPipeline, DisparityResult  # noqa: E402
from uav_depth.core.params import DEFAULT_PARAMS, load_params  # noqa: E402
from uav_depth.core.ranging import Ranger, RangingConfig, default_roi  # noqa: E402
from uav_depth.sim.scene import Scene, SceneConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DISTANCES = (0.4, 0.6, 0.8, 1.0, 1.3, 1.6, 2.0, 2.5, 3.0)


def both(ranger: Ranger, res: DisparityResult) -> tuple[float | None, float | None]:
    m = ranger.measure(DisparityResult(res.measured, res.measured, res.confidence))
    w = ranger.measure(DisparityResult(res.disparity, res.disparity, res.confidence))
    return m.distance_m, w.distance_m


def rel(x: float | None, t: float | None) -> float | None:
    return None if x is None or t is None else (x - t) / t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--seeds", type=int, default=2)
    args = ap.parse_args(argv)
    sets = {"baseline": DEFAULT_PARAMS, "flight": load_params(ROOT / "deploy" / "params-flight.yaml")}
    out: dict[str, dict[str, list[float | None]]] = {}
    print(machine_line())
    for pname, params in sets.items():
        pipe = DisparityPipeline(params, FAITHFUL)
        for seed in range(args.seeds):
            for d in DISTANCES:
                cfg = SceneConfig(seed=seed, branch_distance_m=d, branch_radius_m=0.03)
                f = Scene(cfg).render(rng=np.random.default_rng(seed))
                truth = f.truth(cfg.center_roi).significant_m
                a, b = both(Ranger(RangingConfig(), cfg.calibration, cfg.center_roi, params), pipe.run(f.left, f.right))
                row = out.setdefault(f"synthetic {pname}", {"measured": [], "WLS": []})
                row["measured"].append(rel(a, truth))
                row["WLS"].append(rel(b, truth))
        for name in SCENES:
            left, right, gt = load_scene(args.data, name)
            cal = calibration_for(gt)
            roi = default_roi(cal.width, cal.height)
            ref = Ranger(RangingConfig(), cal, roi, DEFAULT_PARAMS).measure(DisparityResult(gt, gt, None)).distance_m
            a, b = both(Ranger(RangingConfig(), cal, roi, params), pipe.run(left, right))
            row = out.setdefault(f"real {pname}", {"measured": [], "WLS": []})
            row["measured"].append(rel(a, ref))
            row["WLS"].append(rel(b, ref))
    print(f"{'set':20s} {'ranged on':9s} {'n':>3s} {'none':>4s} {'within 2%':>9s} {'farther>2%':>10s} "
          f"{'median|e|':>9s} {'worst':>8s}")
    for key, row in out.items():
        for src, errs in row.items():
            ok = [e for e in errs if e is not None]
            med = f"{np.median(np.abs(ok)) * 100:.2f}%" if ok else "-"
            worst = f"{max(ok, key=abs) * 100:+.2f}%" if ok else "-"
            print(f"{key:20s} {src:9s} {len(errs):3d} {len(errs) - len(ok):4d} {sum(abs(e) <= 0.02 for e in ok):9d} "
                  f"{sum(e > 0.02 for e in ok):10d} {med:>9s} {worst:>8s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
