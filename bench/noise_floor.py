"""Noise floor: what the too-close rules' noise floor buys and costs, side by side in one process.

The noise floor (``core.ranging.too_close.noise_floor``, the ranging's last check) turns a too-close outcome into
"nothing confident" when under 1 % of the region is textured in the left view: the evidence is then the
sensor noise of a featureless surface. Here every frame is measured by the same ``Ranger`` with the check
and without it (the pipeline runs once per frame), with deploy/params-flight.yaml at 1280x720 (f = 700 px,
B = 63 mm):

- what it buys: blank scenes (``contrast: 0``) at each noise level and seed, too close without / with it;
- what it must keep: branches inside the minimum range (0.294 m) for each scene variant, too close without /
  with it (every one must stay too close);
- what it costs: the ranging's milliseconds with and without it, per kind of frame (median of ``--repeats``
  runs, interleaved), on a branch in range (the check returns at once), inside the minimum range and on a
  blank noisy scene (it computes the left view's texture map there).

    .venv/bin/python bench/noise_floor.py
    .venv/bin/python bench/noise_floor.py --seeds 5 --noise 1 2 4 8 12 --repeats 30
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from contextlib import contextmanager

import numpy as np

import scenebench

from uav_depth.cli.benchmark import machine_line
from uav_depth.core.disparity import flight_pipeline
from uav_depth.core.ranging import Ranger, RangingConfig, ranger as ranger_module
from uav_depth.core.ranging.too_close import noise_floor
from uav_depth.sim.scene import Scene, SceneConfig
from uav_depth.sim.sweep import VARIANTS

NEAR_DISTANCES_M = (0.05, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28)


@contextmanager
def without_checks():
    """The ranging without its last checks (the noise floor): what it decided before them."""
    saved = ranger_module.CHECKS
    ranger_module.CHECKS = ()
    try:
        yield
    finally:
        ranger_module.CHECKS = saved


def both(r: Ranger, result):
    """(measurement without the noise floor, with it) of one disparity result."""
    with without_checks():
        before = r.measure(result)
    return before, r.measure(result)


def left_share(r: Ranger, result) -> float:
    """Share of the ROI textured in the left view (what the noise floor reads)."""
    x0, y0, x1, y1 = r.roi
    return float(result.near.left_textured()[y0:y1, x0:x1].mean())


def timed_ms(r: Ranger, result, repeats: int) -> tuple[float, float, float]:
    """Median ms of the ranging without / with the noise floor, interleaved, and of the check alone (on what the
    ranging decided before it)."""
    off, on, alone = [], [], []
    with without_checks():
        decided = r.measure(result)
    for _ in range(repeats):
        with without_checks():
            t0 = time.perf_counter()
            r.measure(result)
            off.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        r.measure(result)
        on.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        noise_floor(r, decided, result)
        alone.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(off), statistics.median(on), statistics.median(alone)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--noise", type=float, nargs="+", default=[1.0, 2.0, 4.0, 8.0])
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    print(machine_line())
    flight = scenebench.param_sets(("flight",))["flight"]
    cal = SceneConfig()
    pipe = flight_pipeline(flight)
    r = Ranger(RangingConfig(), cal.calibration, cal.center_roi, flight)
    print(f"flight file at 1280x720: minimum range {r.limits.min_distance_m:.3f} m")
    costs: dict[str, list[tuple[float, float, float]]] = {"in range (1.0 m)": [], "inside the minimum range": [],
                                                   "blank, noisy": []}
    print("blank scenes (contrast 0): too close without / with the noise floor")
    for std in args.noise:
        counts, shares = [0, 0], []
        for seed in range(args.seeds):
            cfg = SceneConfig(contrast=0.0, noise_std=std, seed=seed)
            frame = Scene(cfg).render(rng=np.random.default_rng([seed, 0]))
            result = pipe.run(frame.left, frame.right)
            before, after = both(r, result)
            counts[0] += before.too_close
            counts[1] += after.too_close
            shares.append(left_share(r, result))
            costs["blank, noisy"].append(timed_ms(r, result, args.repeats))
        print(f"  noise {std:g}: {counts[0]}/{args.seeds} / {counts[1]}/{args.seeds}, left view textured "
              f"{min(shares):.1%}-{max(shares):.1%}")
    print("branches inside the minimum range: too close without / with the noise floor")
    for variant, make in VARIANTS.items():
        counts, n, shares = [0, 0], 0, []
        for seed in range(args.seeds):
            for d in NEAR_DISTANCES_M:
                frame = scenebench.render_cached(make(d, seed))
                result = pipe.run(frame.left, frame.right)
                before, after = both(r, result)
                counts[0] += before.too_close
                counts[1] += after.too_close
                shares.append(left_share(r, result))
                n += 1
                if seed == 0 and d in (0.05, 0.2):
                    costs["inside the minimum range"].append(timed_ms(r, result, args.repeats))
        print(f"  {variant}: {counts[0]}/{n} / {counts[1]}/{n} ({', '.join(f'{d:g}' for d in NEAR_DISTANCES_M)} m), "
              f"left view textured {min(shares):.1%}-{max(shares):.1%}")
    for seed in range(args.seeds):
        frame = scenebench.render_cached(VARIANTS["plain"](1.0, seed))
        costs["in range (1.0 m)"].append(timed_ms(r, pipe.run(frame.left, frame.right), args.repeats))
    print("ranging ms per frame without / with the noise floor, and the check alone (median over frames of each "
          "frame's median)")
    for kind, runs in costs.items():
        off, on, alone = (statistics.median(p[i] for p in runs) for i in range(3))
        print(f"  {kind}: {off:.3f} / {on:.3f} ms, the check alone {alone:.3f} ms ({len(runs)} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
