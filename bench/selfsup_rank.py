"""How well does the reference-free ``selfsup`` loss rank parameter sets, compared with true error?

Draws N random parameter sets from the schema's bounds (params.SPECS; P1/P2
log-uniform inside OpenCV's 16-bit cost limit, other wide ranges log-uniform),
runs the flown pipeline on frames with ground truth, and prints the Spearman rank
correlation of selfsup_loss with true MSE and bad-2 (mean over frames): over all
sets, over the better half (by true MSE: the sets a tuner actually has to choose
between), and what choosing by selfsup would cost (true MSE of its best pick).
The selfsup loss is also recomputed from its parts for other smoothness weights.

    python bench/selfsup_rank.py                       # motorcycle + synthetic, 300 sets each
    python bench/selfsup_rank.py --n 100 --data synth --shape

``--shape`` also draws num_disparities (16..256) and block_size (1..15), narrower
than the schema allows to keep a run to minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from uav_depth.core.disparity import DisparityPipeline
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS, OPENCV_COST_MAX, SPEC_BY_KEY, StereoParams, params_from_dict
from uav_depth.tuning import selfsup
from uav_depth.tuning.metrics import score

SMOOTH_WEIGHTS = (0.0, 0.001, 0.01, 0.1, 1.0)
_FRAMES: list = []


def _bounds(key: str) -> tuple[float, float]:
    s = SPEC_BY_KEY[key]
    return float(s.lo), float(s.hi)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sample_params(rng: np.random.Generator, shape: bool) -> StereoParams:
    """One random parameter set inside the schema's bounds (and OpenCV's cost limit)."""
    p1_lo, _ = _bounds("sgbm.p1")
    p1 = int(_log_uniform(rng, p1_lo, OPENCV_COST_MAX - 1))
    p2 = int(_log_uniform(rng, p1 + 1, OPENCV_COST_MAX))
    d12_lo, d12_hi = _bounds("sgbm.disp12_max_diff")
    d12 = int(d12_lo) if rng.random() < 0.1 else int(_log_uniform(rng, 1, d12_hi + 1)) - 1
    pfc = int(round(_log_uniform(rng, *_bounds("sgbm.pre_filter_cap"))))
    u_lo, u_hi = _bounds("sgbm.uniqueness_ratio")
    uniq = int(rng.integers(u_lo, u_hi + 1))
    sw_lo, sw_hi = _bounds("sgbm.speckle_window_size")
    sw = int(_log_uniform(rng, sw_lo + 1, sw_hi + 1)) - 1
    sr_lo, sr_hi = _bounds("sgbm.speckle_range")
    sr = int(_log_uniform(rng, sr_lo + 1, sr_hi + 1)) - 1
    _, lam_hi = _bounds("wls.lambda")
    lam = _log_uniform(rng, 1.0, lam_hi)
    _, sig_hi = _bounds("wls.sigma_color")
    sig = round(_log_uniform(rng, 0.01, sig_hi), 4)
    d = {"sgbm": {"p1": p1, "p2": p2, "disp12_max_diff": d12, "pre_filter_cap": pfc, "uniqueness_ratio": uniq,
                  "speckle_window_size": sw, "speckle_range": sr},
         "wls": {"enabled": bool(rng.random() < 0.8), "lambda": round(lam, 2), "sigma_color": sig}}
    if shape:
        d["sgbm"]["num_disparities"] = int(16 * rng.integers(1, 17))
        d["sgbm"]["block_size"] = int(2 * rng.integers(0, 8) + 1)
    return params_from_dict(d)


def _load_frames(data: str, synth_dir: str | None) -> list:
    if data == "motorcycle":
        import cv2
        from skimage import data as skdata

        left, right, gt = skdata.stereo_motorcycle()
        return [(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR),
                 gt.astype(np.float32))]
    from uav_depth.core.session import iter_frames

    return [(*f.load_pair(), f.load_reference()) for f in iter_frames(synth_dir, require_reference=True)]


def _init(data: str, synth_dir: str | None) -> None:
    warnings.simplefilter("ignore")
    _FRAMES[:] = _load_frames(data, synth_dir)


def evaluate(params: StereoParams) -> dict:
    """Per-frame selfsup parts and true metrics for one parameter set."""
    pipe = DisparityPipeline(params)
    rows = []
    for left, right, gt in _FRAMES:
        disp = pipe.compute(left, right)
        t = selfsup.selfsup_terms(left, right, disp)
        s = score(gt, disp)
        rows.append({"loss": t.loss, "photo": t.photo, "smooth": t.smooth, "usable": t.usable, "mse": s.mse,
                     "bad2": s.bad2, "valid": s.valid})
    return {"params": params.to_dict(), "frames": rows}


def loss_with_weight(row: dict, w: float) -> float:
    """selfsup_loss of one frame recomputed from its parts for smoothness weight ``w``."""
    if row["usable"] == 0:
        return selfsup.INVALID_COST
    usable_cost = (row["photo"] + w * row["smooth"]) / (1.0 + w)
    return row["usable"] * usable_cost + (1.0 - row["usable"]) * selfsup.INVALID_COST


def _rho(a: np.ndarray, b: np.ndarray) -> float:
    return float(spearmanr(a, b).statistic)


def summarise(results: list[dict], baseline: dict) -> dict:
    mean = lambda r, k: float(np.mean([f[k] for f in r["frames"]]))  # noqa: E731
    mse = np.array([mean(r, "mse") for r in results])
    bad2 = np.array([mean(r, "bad2") for r in results])
    out = {"sets": len(results), "baseline": {"mse": mean(baseline, "mse"), "bad2": mean(baseline, "bad2"),
                                              "selfsup": mean(baseline, "loss")}, "weights": {}}
    better = mse <= np.median(mse)
    order_mse = np.argsort(mse)
    for w in SMOOTH_WEIGHTS:
        loss = np.array([np.mean([loss_with_weight(f, w) for f in r["frames"]]) for r in results])
        pick = int(np.argmin(loss))
        top10 = set(np.argsort(loss)[:10]) & set(order_mse[:10])
        out["weights"][str(w)] = {
            "rho_mse": _rho(loss, mse), "rho_bad2": _rho(loss, bad2),
            "rho_mse_better_half": _rho(loss[better], mse[better]),
            "rho_bad2_better_half": _rho(loss[better], bad2[better]),
            "pick_mse": float(mse[pick]), "pick_bad2": float(bad2[pick]),
            "pick_mse_rank": int(np.where(order_mse == pick)[0][0]) + 1,
            "top10_overlap": len(top10),
        }
    # Per frame, at the default weight: one frame where SGBM is fooled without the photometric error
    # noticing (repetitive texture) can dominate the mean MSE of a whole set.
    out["per_frame"] = []
    for i in range(len(baseline["frames"])):
        fl = np.array([loss_with_weight(r["frames"][i], selfsup.W_SMOOTH) for r in results])
        fm = np.array([r["frames"][i]["mse"] for r in results])
        fb = np.array([r["frames"][i]["bad2"] for r in results])
        out["per_frame"].append({"rho_mse": _rho(fl, fm), "rho_bad2": _rho(fl, fb),
                                 "baseline_mse": baseline["frames"][i]["mse"]})
    out["best_mse"] = float(mse.min())
    out["best_bad2"] = float(bad2.min())
    out["median_mse"] = float(np.median(mse))
    return out


def run(data: str, n: int, seed: int, shape: bool, workers: int, synth_dir: str | None) -> dict:
    rng = np.random.default_rng(seed)
    sets = [sample_params(rng, shape) for _ in range(n)]
    t0 = time.perf_counter()
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_init, initargs=(data, synth_dir)) as pool:
        results = pool.map(evaluate, sets, chunksize=4)
        baseline = pool.apply(evaluate, (DEFAULT_PARAMS,))
    summary = summarise(results, baseline)
    summary.update(data=data, shape=shape, seed=seed, seconds=round(time.perf_counter() - t0, 1),
                   frames=len(baseline["frames"]))
    return summary


def _print(s: dict) -> None:
    print(f"\n== {s['data']} ({s['frames']} frame(s)), {s['sets']} random sets"
          f"{' incl. num_disparities/block_size' if s['shape'] else ''}, seed {s['seed']}, {s['seconds']} s")
    b = s["baseline"]
    print(f"   manual baseline: mse {b['mse']:.1f} bad2 {b['bad2']:.1f}% selfsup {b['selfsup']:.4f}; "
          f"random sets: best mse {s['best_mse']:.1f}, median mse {s['median_mse']:.1f}")
    print(f"   {'w_smooth':>8} {'rho(mse)':>9} {'rho(bad2)':>10} {'rho(mse)|better half':>21} "
          f"{'rho(bad2)|better half':>22} {'pick mse':>9} {'pick rank':>10} {'top10':>6}")
    for w, r in s["weights"].items():
        mark = " <- default" if float(w) == selfsup.W_SMOOTH else ""
        print(f"   {w:>8} {r['rho_mse']:9.3f} {r['rho_bad2']:10.3f} {r['rho_mse_better_half']:21.3f} "
              f"{r['rho_bad2_better_half']:22.3f} {r['pick_mse']:9.1f} {r['pick_mse_rank']:10d} "
              f"{r['top10_overlap']:6d}{mark}")
    if len(s["per_frame"]) > 1:
        print("   per frame (default weight), rho(mse)/rho(bad2) [baseline mse]: " + "; ".join(
            f"{i}: {f['rho_mse']:.2f}/{f['rho_bad2']:.2f} [{f['baseline_mse']:.0f}]" for i, f in enumerate(s["per_frame"])))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=300, help="random parameter sets per data set (default 300)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", choices=("motorcycle", "synth", "both"), default="both")
    p.add_argument("--shape", action="store_true", help="also draw num_disparities and block_size")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--synth-frames", type=int, default=4)
    p.add_argument("--synth-size", default="640x360", help="WxH of the synthetic frames (default 640x360)")
    p.add_argument("--json", help="also write the summaries to this file")
    args = p.parse_args(argv)
    if args.n < 3:
        raise ConfigError("--n", "must be at least 3", args.n)
    summaries = []
    with tempfile.TemporaryDirectory() as tmp:
        synth_dir = None
        if args.data in ("synth", "both"):
            w, h = (int(v) for v in args.synth_size.split("x"))
            synth_dir = str(Path(tmp) / "synth")
            # Same f*B/width as the default rig, so disparities stay in SGBM's default range.
            subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "synth", synth_dir, "--frames",
                            str(args.synth_frames), "--seed", str(args.seed), "--width", str(w), "--height", str(h),
                            "--focal-px", str(700.0 * w / 1280.0)], check=True, capture_output=True)
        for data in (("motorcycle", "synth") if args.data == "both" else (args.data,)):
            s = run(data, args.n, args.seed, args.shape, args.workers, synth_dir)
            _print(s)
            summaries.append(s)
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
