"""Shared by the scene benchmarks (near_sweep, leafy_suite, real_ranging): parameter sets,
cached synthetic frames, and one frame measured as the daemon does and put on the wire.

A frame goes through the real ``flight_pipeline``, the daemon's ``Ranger`` and
``link.contract.distance_report``: the distance judged is what DISTANCE_SENSOR would carry
when its condition is "measuring" (``current_distance`` in cm); "too close" is that
report's condition (the wire's: a reading at or inside the minimum range, or an
estimate the ranging marks ``too_close``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uav_depth.core.disparity import DisparityResult, flight_pipeline
from uav_depth.core.params import DEFAULT_PARAMS, StereoParams, load_params, read_provenance
from uav_depth.daemon.link.contract import distance_report
from uav_depth.daemon.link.conditions import Condition
from uav_depth.core.ranging import Ranger, RangingConfig
from uav_depth.daemon.estimate import Estimate
from uav_depth.sim.scene import SceneConfig
from uav_depth.sim.sweep import render

ROOT = Path(__file__).resolve().parents[1]
FLIGHT_FILE = ROOT / "deploy" / "params-flight.yaml"
CACHE_DIR = Path(os.environ.get("UAV_DEPTH_SCENE_CACHE", "/tmp/uav-depth-scene-cache"))


#: Parameter sets a benchmark can name: the two that fly, and the flight file without / with its fine pass.
PARAM_SET_NAMES = ("baseline", "flight", "flight-coarse", "flight-fine")


def param_sets(names=("baseline", "flight")) -> dict[str, StereoParams]:
    """The manual baseline (core.params DEFAULT_PARAMS), deploy/params-flight.yaml, and that file with the
    fine pass off (``flight-coarse``) or on at 32 disparities (``flight-fine``)."""
    sets = {"baseline": lambda: DEFAULT_PARAMS, "flight": lambda: load_params(FLIGHT_FILE),
            "flight-coarse": lambda: load_params(FLIGHT_FILE).replace(**{"compute.fine_disparities": 0}),
            "flight-fine": lambda: load_params(FLIGHT_FILE).replace(**{"compute.fine_disparities": 32})}
    return {n: sets[n]() for n in names}


def flight_max_range_m() -> float:
    """The far end of the flight file's working distance (provenance), 3.0 m today."""
    prov = read_provenance(FLIGHT_FILE)
    wd = prov.get("working_distance_m") or [0.3, 3.0]
    return float(wd[1])


@dataclass(frozen=True)
class Rendered:
    left: np.ndarray
    right: np.ndarray
    truth_m: float          # nearest significant object in the ranging region (sim/truth.py)
    nearest_any_m: float    # nearest surface of anything there, needles included
    target_m: float         # nearest surface of the target branch there
    disparity: np.ndarray   # exact left disparity, px (0 on the sky)
    truth_thickness_m: float = math.nan   # that object's thickness (inf: the background plane; NaN: none)


def render_cached(cfg: SceneConfig, cache: bool = True) -> Rendered:
    """Render ``cfg`` at the identity pose (noise seeded by its seed), or read it back from the cache.

    The cache key is the config itself (every key), so a changed scene is a miss.
    """
    key = hashlib.sha1(json.dumps(cfg.to_dict(), sort_keys=True).encode()).hexdigest()[:20]
    path = CACHE_DIR / f"{key}.npz"
    if cache and path.exists():
        z = np.load(path)
        if "thick" in z.files:
            return Rendered(z["left"], z["right"], float(z["truth"]), float(z["any"]), float(z["target"]), z["disp"],
                            float(z["thick"]))
    frame = render(cfg)
    roi = cfg.center_roi
    t = frame.truth(roi)
    thick = float(frame.thickness_m[t.object_index]) if t.object_index >= 0 else math.nan
    r = Rendered(frame.left, frame.right, t.significant_m, t.nearest_any_m, frame.nearest_branch_distance(roi),
                 frame.disparity, thick)
    if cache:
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, left=r.left, right=r.right, truth=r.truth_m, any=r.nearest_any_m, target=r.target_m,
                 disp=r.disparity, thick=r.truth_thickness_m)
        os.replace(tmp, path)
    return r


class Measurer:
    """One parameter set's pipeline and ranging for one calibration; ``measure`` a pair."""

    def __init__(self, params: StereoParams, cfg: SceneConfig, ranging: RangingConfig | None = None):
        self.params = params
        self.pipe = flight_pipeline(params)      # what the daemon flies: near check on, no WLS smoothing
        self.ranger = Ranger(ranging or RangingConfig(), cfg.calibration, cfg.center_roi, params)

    @property
    def min_range_m(self) -> float:
        return self.ranger.limits.min_distance_m

    def measure_exact(self, disparity: np.ndarray) -> float | None:
        """The same ranging on the exact disparity (no matcher): the ranging's own error, m."""
        d = np.where(disparity > 0, disparity, np.nan).astype(np.float32)
        return self.ranger.measure(DisparityResult(d, d, None)).distance_m

    def measure(self, left: np.ndarray, right: np.ndarray) -> dict[str, Any]:
        """What the wire would say for this pair: reported_m (None: no measurement), too_close, quality, ms; and the
        ranging's own reading: ranged_m and its 1-sigma sigma_m (m)."""
        t0 = time.perf_counter()
        result = self.pipe.run(left, right)
        m = self.ranger.measure(result)
        ms = (time.perf_counter() - t0) * 1e3
        now = time.monotonic()
        est = Estimate(m, self.ranger.limits, now, now, 0, "bench", too_close=m.too_close)   # as the service does
        rep = distance_report(est, self.ranger.limits, now, 1.0, now)
        return {"reported_m": rep.current_distance / 100.0 if rep.valid else None,
                "ranged_m": m.distance_m, "sigma_m": m.sigma_m, "too_close": rep.condition is Condition.TOO_CLOSE, "condition": rep.condition,
                "quality": rep.signal_quality, "ms": ms, "reason": m.reason}


def add_ranging_args(ap) -> None:
    """The benchmarks' ranging option (read back with :func:`ranging_config`)."""
    ap.add_argument("--thin-guard-cm2", type=float, default=None,
                    help="ranging.thin_guard_m2 in cm^2 (0: off; default: the config's, 4)")


def ranging_config(thin_guard_cm2: float | None = None) -> RangingConfig:
    """The ranging section the benchmarks measure with: the default, or with ``thin_guard_m2`` set (cm^2; 0: off)."""
    return RangingConfig() if thin_guard_cm2 is None else RangingConfig(thin_guard_m2=thin_guard_cm2 * 1e-4)


def rel_err(reported: float | None, truth: float) -> float | None:
    if reported is None or not math.isfinite(truth):
        return None
    return (reported - truth) / truth


def fmt_pct(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:+.2f}%"
