"""Photometric augmentation of bench/tune_real.py's training sessions, for measuring it (docs/tuning.md,
*Measured again (2026-12-06, late morning)*; measured and not built into ``uav-depth tune``).

Copies a ``bench/tune_real.py`` work folder's sessions into a new work folder and gives each training scene
``--frames`` more frames of the same pair, its ground truth unchanged: per frame, a gain (0.8-1.2) and an offset
(-12..12 grey levels) drawn for each eye, Gaussian noise of one level drawn from 1-4 on both, and one eye, drawn
at random, blurred with sigma 0.4-0.9 px. The generator is seeded with the scene's name, so the copy is the same
every time. Then run bench/tune_real.py on the new folder:

    .venv/bin/python bench/tune_real.py --data DIR --work /tmp/tr --skip-default --skip-ga-paper --skip-flight \\
        --skip-synthetic                                    # writes the sessions
    .venv/bin/python bench/augment_sessions.py /tmp/tr /tmp/tra --frames 2
    nice .venv/bin/python bench/tune_real.py --data DIR --work /tmp/tra --population 16 --generations 10 \\
        --skip-ga-paper --skip-flight --skip-synthetic
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from tune_real import TRAIN


def augment(pair: tuple[np.ndarray, np.ndarray], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One photometric variant of a (left, right) uint8 pair (the module docstring's recipe)."""
    left, right = (p.astype(np.float32) for p in pair)
    (gl, gr), (bl, br) = rng.uniform(0.8, 1.2, 2), rng.uniform(-12, 12, 2)
    sigma = rng.uniform(1.0, 4.0)
    left = left * gl + bl + rng.normal(0, sigma, left.shape)
    right = right * gr + br + rng.normal(0, sigma, right.shape)
    if rng.random() < 0.5:
        right = cv2.GaussianBlur(right, (0, 0), rng.uniform(0.4, 0.9))
    else:
        left = cv2.GaussianBlur(left, (0, 0), rng.uniform(0.4, 0.9))
    return tuple(np.clip(p, 0, 255).astype(np.uint8) for p in (left, right))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path, help="a bench/tune_real.py work folder (its sessions/ are read)")
    ap.add_argument("dst", type=Path, help="the new work folder (its sessions/ are replaced)")
    ap.add_argument("--frames", type=int, default=2, help="augmented frames per training scene")
    args = ap.parse_args()
    for src in sorted((args.src / "sessions").iterdir()):
        dest = args.dst / "sessions" / src.name
        if dest.exists():
            shutil.rmtree(dest)
        shutil.copytree(src, dest)
        if src.name not in TRAIN:
            continue
        f = dest / "frames"
        pair = tuple(cv2.imread(str(f / f"000000_{eye}.png")) for eye in ("left", "right"))
        rng = np.random.default_rng([sum(map(ord, src.name)), 44])
        for k in range(1, args.frames + 1):
            for eye, img in zip(("left", "right"), augment(pair, rng)):
                cv2.imwrite(str(f / f"{k:06d}_{eye}.png"), img)
            for suffix in ("_meta.json", "_ref.npy"):
                shutil.copy(f / f"000000{suffix}", f / f"{k:06d}{suffix}")
            ref = json.loads((f / "000000_ref.json").read_text())
            ref["check"]["frames"] = [f"{src.name}/{k:06d}"]
            (f / f"{k:06d}_ref.json").write_text(json.dumps(ref, indent=1))
        print(f"{src.name}: {args.frames} augmented frames")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
