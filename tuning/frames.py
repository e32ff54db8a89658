"""The frames a tuning run scores candidates on, loaded once and split into train / held-out.

A :class:`FrameSet` is plain arrays (picklable), so an executor ships it to each
worker once, at start-up, and never per evaluation. Its :meth:`FrameSet.digest`
names its content in the evaluation cache.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.session import FrameRecord, find_sessions, iter_frames

from uav_depth.tuning.reference.provenance import describe_source, read_provenance


@dataclass(frozen=True, eq=False)
class FrameData:
    """One stereo pair and what is known about it.

    ``left``/``right``: uint8 (H, W) or (H, W, 3). ``reference``: (H, W) float32
    px, NaN unknown. ``branch_mask``: (H, W) bool (synthetic sessions).
    ``branch_distance_m``: truth of the nearest branch surface inside ``roi``
    (x0, y0, x1, y1) px. ``focal_px`` and ``baseline_m`` turn disparity into
    metres. A frame is scored by the branch fitness when it has the truth and
    the calibration.
    """

    key: str
    left: np.ndarray
    right: np.ndarray
    reference: np.ndarray | None = None
    branch_mask: np.ndarray | None = None
    branch_distance_m: float | None = None
    roi: tuple[int, int, int, int] | None = None
    focal_px: float | None = None
    baseline_m: float | None = None
    #: Where the reference came from, one line (``uav_depth.tuning.reference.provenance.describe``);
    #: reports say what the tuning was measured against. Not part of the digest: it changes no score.
    reference_source: str | None = None

    @property
    def has_branch(self) -> bool:
        return (self.branch_distance_m is not None and math.isfinite(self.branch_distance_m) and self.focal_px is not None
                and self.baseline_m is not None)

    def has(self, need: str) -> bool:
        return {"reference": self.reference is not None, "branch": self.has_branch}[need]


@dataclass(frozen=True, eq=False)
class FrameSet:
    """Named, ordered frames (``train`` or ``holdout``)."""

    name: str
    frames: tuple[FrameData, ...]

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def keys(self) -> list[str]:
        return [f.key for f in self.frames]

    def digest(self) -> str:
        """Hash of every array and number of every frame: same digest, same evaluations."""
        h = hashlib.sha256()
        for f in self.frames:
            h.update(f.key.encode())
            for arr in (f.left, f.right, f.reference, f.branch_mask):
                if arr is None:
                    h.update(b"-")
                else:
                    a = np.ascontiguousarray(arr)
                    h.update(f"{a.dtype}{a.shape}".encode())
                    h.update(a.tobytes())
            h.update(repr((f.branch_distance_m, f.roi, f.focal_px, f.baseline_m)).encode())
        return h.hexdigest()[:16]

    def reference_sources(self) -> dict[str, int]:
        """Where this set's references came from: description -> number of frames."""
        out: dict[str, int] = {}
        for f in self.frames:
            if f.reference is not None:
                src = f.reference_source or "unknown"
                out[src] = out.get(src, 0) + 1
        return out

    def filter(self, needs: Iterable[str]) -> "FrameSet":
        needs = tuple(needs)
        return FrameSet(self.name, tuple(f for f in self.frames if all(f.has(n) for n in needs)))


def load_frame(record: FrameRecord) -> FrameData:
    """Read one logged frame with its reference, branch mask and truth when present."""
    left, right = record.load_pair()
    ref = record.load_reference()
    if ref is not None and ref.shape != left.shape[:2]:
        raise FileFormatError(f"{record.ref_path}: reference is {ref.shape}, frame is {left.shape[:2]}")
    mask_path = record.session.frames_dir / f"{record.frame_id}_branch.npy"
    mask = np.load(mask_path).astype(bool) if mask_path.exists() else None
    meta = record.load_meta()
    truth = meta.get("branch_distance_m")
    roi = meta.get("roi")
    focal = baseline = None
    if record.session.calibration_path.exists():
        cal = record.session.calibration()
        focal, baseline = cal.focal_px, cal.baseline_m
    source = describe_source(read_provenance(record)) if ref is not None else None
    return FrameData(record.key, left, right, ref, mask,
                     float(truth) if isinstance(truth, (int, float)) else None,
                     tuple(int(v) for v in roi) if isinstance(roi, list) and len(roi) == 4 else None,
                     focal, baseline, source)


#: Share of a single session's frames "auto" holds out.
AUTO_FRACTION = 0.3


def _is_dir(text: str) -> bool:
    """Whether ``text`` names a directory; False for text no path can be (a list of names longer than the
    system's name limit raises OSError from stat, which is not a directory either)."""
    try:
        return Path(text).is_dir()
    except (OSError, ValueError):
        return False


def split_records(logdir: str | os.PathLike[str], holdout: str | None) -> tuple[list[FrameRecord], list[FrameRecord]]:
    """Train and held-out frame records of ``logdir`` by the ``--holdout`` rule.

    ``holdout`` is one of: empty/None/"none" (no held-out frames); "auto" (by session:
    the last third of the sessions, at least one, when there are two or more; else the
    last 30 % of the frames when there are two or more; else none); a directory (a session
    or a directory of sessions, all held out; the train frames are ``logdir``'s);
    a fraction 0 < f < 1 (the last ceil(f * n) frames of each session, at least one
    frame stays for training); or a comma list of session names, ``session/frame``
    keys or frame ids.
    """
    records = list(iter_frames(logdir))
    if not records:
        raise FileFormatError(f"{logdir}: no frames found")
    if not holdout or holdout == "none":
        return records, []
    if holdout == "auto":
        sessions = find_sessions(logdir)
        if len(sessions) >= 2:
            held_names = {s.path.resolve() for s in sessions[len(sessions) - math.ceil(len(sessions) / 3):]}
            held = [r for r in records if r.session.path.resolve() in held_names]
            return [r for r in records if r not in held], held
        if len(records) < 2:
            return records, []
        holdout = str(AUTO_FRACTION)
    if _is_dir(holdout):
        path = Path(holdout)
        held = list(iter_frames(path))
        held_keys = {(r.session.path.resolve(), r.frame_id) for r in held}
        train = [r for r in records if (r.session.path.resolve(), r.frame_id) not in held_keys]
        return train, held
    try:
        fraction = float(holdout)
    except ValueError:
        fraction = None
    if fraction is not None:
        if not 0 < fraction < 1:
            raise ConfigError("--holdout", "must be a fraction between 0 and 1, a directory or a list of names",
                              holdout)
        train, held = [], []
        for session in find_sessions(logdir):
            frames = session.frames()
            k = min(math.ceil(fraction * len(frames)), len(frames) - 1)
            train += frames[:len(frames) - k]
            held += frames[len(frames) - k:]
        return train, held
    names = {n.strip() for n in holdout.split(",") if n.strip()}
    matched: set[str] = set()
    held = []
    for r in records:
        hit = {r.session.path.name, r.key, r.frame_id} & names
        if hit:
            held.append(r)
            matched |= hit
    unknown = names - matched
    if unknown:
        raise ConfigError("--holdout", "must name sessions, session/frame keys or frame ids of the log",
                          ", ".join(sorted(unknown)))
    return [r for r in records if r not in held], held


def load_split(logdir: str | os.PathLike[str], holdout: str | None, needs: Iterable[str]) -> tuple[FrameSet, FrameSet]:
    """Load train and held-out frames that have what the fitness ``needs`` (reference, branch)."""
    needs = tuple(needs)
    train_r, held_r = split_records(logdir, holdout)
    train = FrameSet("train", tuple(load_frame(r) for r in train_r)).filter(needs)
    held = FrameSet("holdout", tuple(load_frame(r) for r in held_r)).filter(needs)
    if not len(train):
        what = " and ".join(needs) or "frames"
        hint = ""
        if "reference" in needs:
            hint = ("; give the frames a reference disparity (uav-depth reference import LOGDIR --from DIR, or "
                    "uav-depth reference onnx), or tune without one: --metric selfsup")
        elif "branch" in needs:
            hint = "; the branch metric needs each frame's branch_distance_m (synthetic sessions carry it)"
        raise FileFormatError(f"{logdir}: no training frame with {what} (after --holdout){hint}")
    return train, held


def load_folds(logdir: str | os.PathLike[str], k: int, needs: Iterable[str]) -> list[tuple[FrameSet, FrameSet]]:
    """k (train, held-out) splits by session: fold j holds out the sessions j, j+k, j+2k ... (name order).

    Each frame is loaded once and shared by the folds. Every fold must keep a training frame with what the
    fitness ``needs``."""
    needs = tuple(needs)
    sessions = find_sessions(logdir)
    if k < 2 or len(sessions) < k:
        raise ConfigError("--folds", f"needs at least as many sessions as folds ({len(sessions)} sessions)", k)
    per_session = [[load_frame(r) for r in s.frames()] for s in sessions]
    folds = []
    for j in range(k):
        train = [f for i, fs in enumerate(per_session) if i % k != j for f in fs]
        held = [f for i, fs in enumerate(per_session) if i % k == j for f in fs]
        train_set = FrameSet("train", tuple(train)).filter(needs)
        if not len(train_set):
            raise FileFormatError(f"{logdir}: fold {j + 1} of {k} has no training frame with "
                                  f"{' and '.join(needs) or 'frames'}")
        folds.append((train_set, FrameSet("holdout", tuple(held)).filter(needs)))
    return folds
