"""The tuning report: JSON summary, convergence and Pareto plots, the paper-style table, images.

Files written into the report directory:

- ``summary.json``: configuration, per-run results and histories, baseline vs
  tuned metrics on the train, validation and test frames, which frames were which, the gate's verdict,
  the Pareto front, timings;
- ``table.md``: the change of MSE, PSNR, SSIM, bad-2 (and branch error when
  known) of the tuned parameters against the base (``--base``, by default the manual baseline), train and
  validation and test, next to the paper's reported change, the gate's line and the choice's candidates;
- ``convergence.png``: best fitness so far per generation, mean +- std over runs
  (the paper's figure), with the baseline as a line;
- ``pareto.png``: fitness against frame time for every evaluated candidate;
- ``frames/*.png``: reference | base | tuned disparity side by side;
- ``config.yaml``: the resolved configuration of the run.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from uav_depth.core.disparity import MEASURED, DisparityPipeline
from uav_depth.core.params import StereoParams
from uav_depth.core.session import colourise

from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.objective import FITNESS, Evaluation, flown_map

#: The paper's reported change of its tuned parameters against its manual configuration, %.
PAPER_CHANGE = {"mse": -42.86, "psnr": 8.47, "ssim": 28.52}
TABLE_METRICS = ("mae", "rmse", "mse", "psnr", "ssim", "bad1", "bad2", "bad4", "branch", "branch_safe", "farther",
                 "density", "valid")


def change_pct(base: float, tuned: float) -> float:
    """(tuned - base) / |base| in %, NaN when undefined."""
    if not (math.isfinite(base) and math.isfinite(tuned)) or base == 0:
        return math.nan
    return (tuned - base) / abs(base) * 100.0


def comparison(baseline: Mapping[str, Evaluation], tuned: Mapping[str, Evaluation]) -> dict[str, dict]:
    """{set: {metric: {"base", "tuned", "change_pct"}}} from full evaluations per frame set.

    The base is what the search started from (``--base``, by default the manual baseline)."""
    out: dict[str, dict] = {}
    for name in baseline:
        b, t = baseline[name], tuned[name]
        rows = {}
        for m in TABLE_METRICS:
            if m in b.metrics and m in t.metrics:
                rows[m] = {"base": b.metrics[m], "tuned": t.metrics[m],
                           "change_pct": change_pct(b.metrics[m], t.metrics[m])}
        rows["ms"] = {"base": b.ms, "tuned": t.ms, "change_pct": change_pct(b.ms, t.ms)}
        out[name] = {"frames": len(b.per_frame), "status": {"base": b.status, "tuned": t.status},
                     "metrics": rows}
    return out


def sources_text(sources: Mapping[str, int]) -> str:
    """``8 x synthetic (exact ray-cast disparity), 2 x onnx raft.onnx (...)``: what frames were measured against."""
    return ", ".join(f"{n} x {src}" for src, n in sources.items())


#: How reports name the default base.
MANUAL_BASELINE = "the manual baseline (OpenCV's sample values)"


CONVENTION_TEXT = {
    "bench": "benchmark convention (the map the daemon ranges on: confident measured pixels; error over "
             "ground-truth pixels, holes filled along the row as the KITTI devkit does, density beside it, the "
             "unmatchable left strip left out, PSNR against the search range)",
    "paper": "the paper's convention (the WLS map; unanswered pixels count as 0, PSNR peak per frame)",
}


def table_markdown(cmp: Mapping[str, dict], metric: str, references: Mapping[str, Mapping[str, int]] | None = None,
                   base: str = MANUAL_BASELINE, convention: str = "paper",
                   selection: Mapping[str, Any] | None = None, gate: Mapping[str, Any] | None = None,
                   notes: Sequence[str] = ()) -> str:
    lines = [f"Tuned ({metric}) vs the base it started from: {base}. Metrics: {CONVENTION_TEXT[convention]}."
             + (" Paper: its tuned vs manual configuration, one pair." if convention == "paper" else ""), "",
             "Frames: the search trained on the train frames, the choice was made on the validation frames, "
             "and the gate judged on the test frames, which nothing in the choice saw (summary.json: frames)."]
    lines += [f"**Note:** {note}." for note in notes]
    lines.append("")
    lines += [f"Reference disparity of the {name} frames: {sources_text(sources)}."
              for name, sources in (references or {}).items() if sources]
    lines += ["", "| frames | metric | base | tuned | change | paper's change |", "|---|---|---|---|---|---|"]
    for name, block in cmp.items():
        for m, row in block["metrics"].items():
            paper = f"{PAPER_CHANGE[m]:+.2f}%" if m in PAPER_CHANGE and convention == "paper" else ""
            lines.append(f"| {name} ({block['frames']}) | {m} | {_f(row['base'])} | {_f(row['tuned'])} | "
                         f"{_pct(row['change_pct'])} | {paper} |")
    if gate:
        lines += ["", _gate_line(metric, gate)]
    if selection:
        lines += _selection_lines(metric, selection)
    return "\n".join(lines) + "\n"


def _gate_line(metric: str, gate: Mapping[str, Any]) -> str:
    verdict = "refused: " + gate["refused"] if gate.get("refused") else "passed"
    return (f"Gate, on the {gate['frames']} {gate['on']} frame(s): {metric} base {_f(gate['base'])}, tuned "
            f"{_f(gate['tuned'])}; {verdict}.")


def _selection_lines(metric: str, selection: Mapping[str, Any]) -> list[str]:
    lines = ["", f"Choice on the {selection['on']} frames among the best training candidates ({metric}; "
             "fragile ones cannot win):", "", "| candidate | train | validation | note |", "|---|---|---|---|"]
    for i, row in enumerate(selection["candidates"]):
        note = "base" if i == 0 else ""
        if i == selection["winner"]:
            note = (note + " chosen").strip()
        if row.get("fragile"):
            note = (note + " rejected: " + row["fragile"]).strip()
        lines.append(f"| {i} | {_f(row['train'])} | {_f(row['validation'])} | {note} |")
    folds = selection.get("folds") or []
    if len(folds) > 1:
        lines += ["", f"{len(folds)}-fold by session: each fold searched on its training sessions and chose on its "
                  "own validation ones (above: the fold winners, validation = mean over the folds, which includes "
                  "the sessions each trained on; the winner has the largest gain over the base on its own fold's):",
                  "", "| fold | train frames | validation frames | base train | winner train | base validation | "
                  "winner validation |", "|---|---|---|---|---|---|---|"]
        for f in folds:
            lines.append(f"| {f['fold']} | {len(f['train_frames'])} | {len(f['validation_frames'])} | "
                         f"{_f(f['base_train'])} | {_f(f['winner_train'])} | {_f(f['base_validation'])} | "
                         f"{_f(f['winner_validation'])} |")
    return lines


def _f(x: float) -> str:
    if not isinstance(x, (int, float)) or not math.isfinite(x):
        return str(x)
    return f"{x:.4g}" if abs(x) < 1000 else f"{x:.0f}"


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{x:+.2f}%"


def _clean(obj: Any) -> Any:
    """JSON-safe copy: non-finite floats become null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return _clean(obj.item())
    return obj


def plot_convergence(path: Path, histories: Sequence[Sequence[float]], baseline: float, metric: str,
                     title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = np.array([[v if math.isfinite(v) else np.nan for v in run] for run in histories], dtype=float)
    gens = np.arange(1, h.shape[1] + 1)
    fig, ax = plt.subplots(figsize=(6, 4))
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, std = np.nanmean(h, axis=0), np.nanstd(h, axis=0)
    ax.plot(gens, mean, label=f"best so far, mean of {h.shape[0]} run(s)")
    if h.shape[0] > 1:
        ax.fill_between(gens, mean - std, mean + std, alpha=0.3, label="+- std")
    if math.isfinite(baseline):
        ax.axhline(baseline, color="k", ls="--", lw=1, label="base")
    ax.set_xlabel("generation")
    ax.set_ylabel(metric)
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_pareto(path: Path, points: Sequence[tuple[float, float]], front: Sequence[Mapping[str, Any]],
                chosen: Mapping[str, Any] | None, metric: str, max_ms: float | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    if points:
        ms, val = zip(*points)
        ax.scatter(ms, val, s=6, alpha=0.4, label="evaluated (search timing)")
        # the interesting part: the better half of the candidates (failures and wild ones off-scale)
        v = np.asarray(val, float)
        lo, hi = np.percentile(v, [0, 50]) if FITNESS[metric].direction < 0 else np.percentile(v, [50, 100])
        pad = 0.05 * (hi - lo) if hi > lo else 1.0
        ax.set_ylim(lo - pad, hi + pad)
    if front:
        timed = "re-timed" if any("search_ms" in f for f in front) else "search timing"
        ax.plot([f["ms"] for f in front], [f["value"] for f in front], "o-", color="C1", label=f"front, {timed}")
    if chosen:
        ax.plot([chosen["ms"]], [chosen["value"]], "*", ms=14, color="C3", label="chosen")
    if max_ms:
        ax.axvline(max_ms, color="k", ls="--", lw=1, label=f"--max-ms {max_ms:g}")
    ax.set_xlabel("ms per frame")
    ax.set_ylabel(metric)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def side_by_side(path: Path, frame, base: StereoParams, tuned: StereoParams) -> None:
    """reference | base | tuned disparity (one colour scale) as one PNG: the map the daemon ranges on."""
    import cv2

    maps = [flown_map(DisparityPipeline(p, MEASURED).run(frame.left, frame.right)) for p in (base, tuned)]
    if frame.reference is not None:
        maps.insert(0, frame.reference)
    finite = [m[np.isfinite(m)] for m in maps]
    top = max((float(f.max()) for f in finite if f.size), default=1.0)
    tiles = [colourise(m, top) for m in maps]
    labels = (["reference"] if frame.reference is not None else []) + ["base", "tuned"]
    for tile, label in zip(tiles, labels):
        cv2.putText(tile, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    cv2.imwrite(str(path), np.hstack(tiles))


def write_report(outdir: str | Path, summary: Mapping[str, Any], config: Mapping[str, Any],
                 framesets: Sequence[FrameSet], base: StereoParams, tuned: StereoParams,
                 pareto_points: Sequence[tuple[float, float]], images_per_set: int = 2,
                 progress: Callable[[int, int], None] = lambda done, total: None) -> Path:
    """Write every report file into ``outdir`` (created); returns the directory. ``progress(done, total)``
    after the plots and each image (each image runs both parameter sets on one frame)."""
    out = Path(outdir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    metric = summary["config"]["metric"]
    (out / "summary.json").write_text(json.dumps(_clean(summary), indent=1))
    (out / "config.yaml").write_text(yaml.safe_dump(_clean(config), sort_keys=False))
    if summary.get("comparison"):
        (out / "table.md").write_text(table_markdown(summary["comparison"], metric, summary.get("references"),
                                                     summary.get("base", MANUAL_BASELINE),
                                                     summary.get("convention", "paper"), summary.get("selection"),
                                                     summary.get("gate"), summary.get("notes") or ()))
    runs = summary["runs"]
    plot_convergence(out / "convergence.png", [r["history"] for r in runs], summary["baseline"]["value"], metric,
                     f"{summary['config']['optimizer']}, {metric} "
                     f"({'min' if FITNESS[metric].direction < 0 else 'max'}imised)")
    budget = summary.get("budget") or {}
    plot_pareto(out / "pareto.png", pareto_points, budget.get("front") or [], budget.get("chosen"), metric,
                budget.get("max_ms"))
    images = [(fs, frame) for fs in framesets for frame in fs.frames[:images_per_set]]
    progress(1, len(images) + 1)
    for i, (fs, frame) in enumerate(images, 2):
        side_by_side(out / "frames" / f"{fs.name}_{frame.key.replace('/', '_')}.png", frame, base, tuned)
        progress(i, len(images) + 1)
    return out
