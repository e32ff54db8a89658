"""Identical readings: every reading of the ranging benchmarks recorded field by field, and two records compared.

A refactor of the disparity stages or the ranging that claims to change nothing is
checked here: record before, record after, ``--compare``. A reading is one frame
through one parameter set's pipeline and the daemon's ranging (and, for the
synthetic and real scenes, the same ranging on the exact disparity). Recorded per
reading: the ranging's whole result (distance, sigma, quality, reason text and code,
too_close, refined, guarded, bbox, disparity_px, sigma_px, n_px, valid_fraction) and
what DISTANCE_SENSOR would carry for it (condition, min/max/current distance,
covariance, signal quality, fields of view), at a fixed clock so that the record is
reproducible.

The readings are those of:

- ``near``: bench/near_sweep.py's sweep (both parameter sets, the three variants,
  seeds 0-4, 1 cm from 0.05 m to the flight file's far working distance; renders
  are cached as near_sweep caches them). The whole sweep is about 1.2 CPU-s a frame
  for 4440 frames; ``--near-dense-to-m 0.5 --near-far-step-m 0.05`` keeps 1 cm steps
  where the too-close rules act and 5 cm beyond (1440 frames);
- ``leafy``: bench/leafy_suite.py's 30 scenes, both parameter sets;
- ``real``: bench/real_ranging.py's 17 Middlebury pairs (``--data``), both parameter
  sets, and the reference ranging on the ground truth;
- ``bench``: ``uav-depth bench``'s readings: its 12 frames through each of its default
  variants (naive, flight+WLS, flight-noSmooth, flight) with the built-in flight
  settings, and its ranging on the exact disparity.

    .venv/bin/python bench/identical_readings.py --out before.json          # every set, full size
    .venv/bin/python bench/identical_readings.py --out before.json --near-dense-to-m 0.5 --near-far-step-m 0.05
    .venv/bin/python bench/identical_readings.py --out q.json --near-seeds 1 --near-step-m 0.1
    .venv/bin/python bench/identical_readings.py --compare before.json after.json

``--compare`` prints how many readings were compared and every difference (set, reading,
field, both values); it exits 1 when any reading differs or is missing on one side.
A field recorded on one side only (a new field) is listed apart and is not a difference.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import sys
import time
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import leafy_suite  # noqa: E402
import near_sweep  # noqa: E402
import real_ranging  # noqa: E402
import scenebench  # noqa: E402

from uav_depth.cli import benchmark  # noqa: E402
from uav_depth.core.disparity import DisparityPipeline, DisparityResult, flight_pipeline  # noqa: E402
from uav_depth.core.params import DEFAULT_PARAMS  # noqa: E402
from uav_depth.daemon.link.contract import distance_report  # noqa: E402
from uav_depth.sim.scene import SceneConfig  # noqa: E402
from uav_depth.sim.sweep import VARIANTS  # noqa: E402

from uav_depth.core.disparity import FAITHFUL, MEASURED  # noqa: E402
from uav_depth.core.params.flight import flight_params  # noqa: E402
from uav_depth.core.ranging import Ranger, RangingConfig, default_roi  # noqa: E402
from uav_depth.daemon.estimate import Estimate  # noqa: E402


def pipeline(params: Any, smooth: bool) -> DisparityPipeline:
    return DisparityPipeline(params, FAITHFUL if smooth else MEASURED)


SETS = ("near", "leafy", "real", "bench")
#: The fixed clock every DISTANCE_SENSOR is built at: capture and "now" at 100 s after the start, fresh.
T_NOW = 100.0


def _value(v: Any) -> Any:
    """A field as JSON keeps it exactly: floats as they are (repr round-trips), enums by name, tuples as lists."""
    if v is None or isinstance(v, (bool, str)):
        return v
    if hasattr(v, "name") and hasattr(v, "value") and not isinstance(v, (int, float)):   # an Enum
        return v.name
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f if math.isfinite(f) else repr(f)
    if isinstance(v, (tuple, list)):
        return [_value(x) for x in v]
    return repr(v)


def reading(m: Any, limits: Any) -> dict[str, Any]:
    """One Measurement field by field, and the DISTANCE_SENSOR it makes (``wire.*``) at the fixed clock."""
    out = {f.name: _value(getattr(m, f.name)) for f in fields(m)}
    est = Estimate(m, limits, T_NOW, T_NOW, 0, "identical", too_close=m.too_close)   # as the service builds it
    rep = distance_report(est, limits, T_NOW, 1.0, 0.0)
    assert is_dataclass(rep)
    out.update({f"wire.{f.name}": _value(getattr(rep, f.name)) for f in fields(rep)})
    return out


def exact_result(disparity: np.ndarray) -> DisparityResult:
    """The exact disparity as the scene benchmarks range it (scenebench.Measurer.measure_exact)."""
    d = np.where(disparity > 0, disparity, np.nan).astype(np.float32)
    return DisparityResult(d, d, None)


def near_distances(step_m: float, dense_to_m: float | None = None, far_step_m: float | None = None) -> list[float]:
    """bench/near_sweep.py's distances (0.05 m to the flight file's far working distance, ``step_m`` apart); with
    ``dense_to_m``, ``step_m`` apart up to there (where the too-close rules act) and ``far_step_m`` beyond."""
    far = scenebench.flight_max_range_m()
    if dense_to_m is None:
        return near_sweep.distances(0.05, far, step_m)
    near = near_sweep.distances(0.05, dense_to_m, step_m)
    return near + [d for d in near_sweep.distances(dense_to_m, far, far_step_m or step_m) if d > near[-1] + 1e-9]


def _near_part(job: tuple[str, int, list[float], bool]) -> list[tuple[str, dict]]:
    """One (variant, seed) of the near sweep: every distance and parameter set, pipeline and exact."""
    variant, seed, dists, cache = job
    cal = SceneConfig()
    ms = {name: scenebench.Measurer(p, cal) for name, p in scenebench.param_sets(("baseline", "flight")).items()}
    out = []
    for d in dists:
        frame = scenebench.render_cached(VARIANTS[variant](d, seed), cache)
        for name, meas in ms.items():
            key = f"{name}/{variant}/s{seed}/{d:.2f}m"
            out.append((key, reading(meas.ranger.measure(meas.pipe.run(frame.left, frame.right)), meas.ranger.limits)))
            out.append((key + "/exact", reading(meas.ranger.measure(exact_result(frame.disparity)),
                                                meas.ranger.limits)))
    return out


def near_readings(seeds: int, dists: list[float], variants: list[str], cache: bool,
                  jobs: int = 1) -> Iterator[tuple[str, dict]]:
    """bench/near_sweep.py's sweep: every (parameter set, variant, seed, distance), pipeline and exact; ``jobs``
    processes, one (variant, seed) each at a time (each reading is computed alone: the same values)."""
    parts = [(v, s, dists, cache) for v in variants for s in range(seeds)]
    if jobs <= 1:
        for part in parts:
            yield from _near_part(part)
        return
    with multiprocessing.get_context("spawn").Pool(jobs) as pool:
        for got in pool.imap(_near_part, parts):
            yield from got


def leafy_readings(n_scenes: int, cache: bool) -> Iterator[tuple[str, dict]]:
    """bench/leafy_suite.py's scenes: every (parameter set, scene), pipeline and exact."""
    sets = scenebench.param_sets(("baseline", "flight"))
    ms = {name: scenebench.Measurer(p, SceneConfig()) for name, p in sets.items()}
    for i in range(n_scenes):
        frame = scenebench.render_cached(leafy_suite.scene(i), cache)
        for name, meas in ms.items():
            yield f"{name}/scene{i}", reading(meas.ranger.measure(meas.pipe.run(frame.left, frame.right)),
                                              meas.ranger.limits)
            yield f"{name}/scene{i}/exact", reading(meas.ranger.measure(exact_result(frame.disparity)),
                                                    meas.ranger.limits)


def real_readings(data: Path) -> Iterator[tuple[str, dict]]:
    """bench/real_ranging.py's 17 pairs: the reference on the ground truth, and each parameter set as it flies."""
    sets = scenebench.param_sets(("baseline", "flight"))
    for name in real_ranging.SCENES:
        left, right, gt = real_ranging.load_scene(data, name)
        cal = real_ranging.calibration_for(gt)
        roi = default_roi(cal.width, cal.height)
        ref = Ranger(RangingConfig(), cal, roi, DEFAULT_PARAMS)
        yield f"reference/{name}", reading(ref.measure(DisparityResult(gt, gt, None)), ref.limits)
        for pname, params in sets.items():
            r = Ranger(RangingConfig(), cal, roi, params)
            yield f"{pname}/{name}", reading(r.measure(flight_pipeline(params).run(left, right)), r.limits)


def bench_readings() -> Iterator[tuple[str, dict]]:
    """``uav-depth bench``'s readings: its default frames through its default variants, and the exact floor."""
    frames = benchmark.make_frames(12, 1280, 720, 0)
    flight = flight_params(focal_px=700.0)
    variants = [("naive", DEFAULT_PARAMS, "smooth"), ("flight+WLS", flight, "smooth"),
                ("flight-noSmooth", flight, "measured"), ("flight", flight, "flies")]
    for vname, params, how in variants:
        pipe = flight_pipeline(params) if how == "flies" else pipeline(params, how == "smooth")
        for i, f in enumerate(frames):
            h, w = f.left.shape[:2]
            r = Ranger(RangingConfig(), f.scene.calibration, default_roi(w, h), params)
            yield f"{vname}/frame{i}", reading(r.measure(pipe.run(f.left, f.right)), r.limits)
    for i, f in enumerate(frames):   # benchmark.ranging_floor: the exact disparity, confidence 1
        h, w = f.left.shape[:2]
        r = Ranger(RangingConfig(), f.scene.calibration, default_roi(w, h), DEFAULT_PARAMS)
        d = np.where(np.isfinite(f.disparity), f.disparity, np.nan).astype(np.float32)
        yield f"exact/frame{i}", reading(r.measure(DisparityResult(d, d, np.ones_like(d))), r.limits)


def record(args: argparse.Namespace, save: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    """Every set's readings; ``save(record)`` after each set (a long run keeps what it has measured)."""
    makers: dict[str, Callable[[], Iterator[tuple[str, dict]]]] = {
        "near": lambda: near_readings(args.near_seeds, dists, args.near_variants, not args.no_cache, args.jobs),
        "leafy": lambda: leafy_readings(args.leafy_scenes, not args.no_cache),
        "real": lambda: real_readings(args.data),
        "bench": bench_readings,
    }
    dists = near_distances(args.near_step_m, args.near_dense_to_m, args.near_far_step_m)
    out: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                           "options": {"near_seeds": args.near_seeds, "near_distances_m": dists,
                                       "near_variants": args.near_variants, "leafy_scenes": args.leafy_scenes,
                                       "data": str(args.data)},
                           "readings": {}, "seconds": {}}
    for name in args.sets:
        t0 = time.monotonic()
        got = out["readings"][name] = {}
        for key, r in makers[name]():
            got[key] = r
            if len(got) % 200 == 0:
                print(f"  {name}: {len(got)} readings, {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
        out["seconds"][name] = round(time.monotonic() - t0, 1)
        print(f"{name}: {len(got)} readings in {out['seconds'][name]:.0f} s (load {os.getloadavg()[0]:.1f})",
              file=sys.stderr, flush=True)
        save(out)
    return out


def compare(a_path: Path, b_path: Path) -> int:
    """Print the readings compared and every difference; 0 when identical, else 1."""
    a, b = json.loads(a_path.read_text()), json.loads(b_path.read_text())
    if a.get("options") != b.get("options"):
        print(f"note: recorded with different options: {a.get('options')} vs {b.get('options')}")
    compared, diffs, missing = 0, [], []
    one_sided: dict[str, int] = {}
    for name in sorted(set(a["readings"]) | set(b["readings"])):
        ra, rb = a["readings"].get(name, {}), b["readings"].get(name, {})
        for key in sorted(set(ra) | set(rb)):
            if key not in ra or key not in rb:
                missing.append(f"{name}/{key}: only in {a_path if key in ra else b_path}")
                continue
            compared += 1
            fa, fb = ra[key], rb[key]
            for field_name in sorted(set(fa) | set(fb)):
                if field_name not in fa or field_name not in fb:
                    one_sided[field_name] = one_sided.get(field_name, 0) + 1
                elif fa[field_name] != fb[field_name]:
                    diffs.append(f"{name}/{key}: {field_name}: {fa[field_name]!r} != {fb[field_name]!r}")
    per_set = ", ".join(f"{n} {len(set(a['readings'].get(n, {})) & set(b['readings'].get(n, {})))}"
                        for n in sorted(set(a["readings"]) | set(b["readings"])))
    print(f"{compared} readings compared ({per_set}), {len(diffs)} differences, {len(missing)} missing")
    for line in missing + diffs:
        print("  " + line)
    for field_name, n in sorted(one_sided.items()):
        print(f"  (field {field_name!r} recorded on one side only, in {n} readings: not compared)")
    return 0 if not diffs and not missing else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the record here (JSON)")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"), help="compare two records")
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    ap.add_argument("--near-seeds", type=int, default=5, help="near sweep seeds 0..N-1 (default 5, as near_sweep)")
    ap.add_argument("--near-step-m", type=float, default=0.01, help="near sweep step (default 0.01, as near_sweep)")
    ap.add_argument("--near-dense-to-m", type=float, default=None,
                    help="near sweep: --near-step-m apart up to this distance only, --near-far-step-m beyond")
    ap.add_argument("--near-far-step-m", type=float, default=None, help="near sweep step beyond --near-dense-to-m")
    ap.add_argument("--near-variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--leafy-scenes", type=int, default=30, help="leafy suite scenes (default 30, as leafy_suite)")
    ap.add_argument("--data", type=Path, default=real_ranging.DEFAULT_DATA, help="the 17 Middlebury 2006 pairs")
    ap.add_argument("--no-cache", action="store_true", help="render the synthetic scenes again")
    ap.add_argument("--jobs", type=int, default=1, help="processes for the near sweep (default 1)")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(*args.compare)
    if args.out is None:
        ap.error("--out FILE (record) or --compare A B")
    if "real" in args.sets and not (args.data / real_ranging.SCENES[0] / "disp1.png").is_file():
        ap.error(f"no Middlebury 2006 scenes at {args.data}: pass --data DIR (or leave out the real set)")
    out = record(args, lambda rec: args.out.write_text(json.dumps(rec, indent=0, sort_keys=True)))
    total = sum(len(v) for v in out["readings"].values())
    print(f"{total} readings written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
