"""The frames a tuning run scores candidates on, loaded once (:mod:`.split` says which frames play which role).

A :class:`FrameSet` is plain arrays (picklable), so an executor ships it to each
worker once, at start-up, and never per evaluation. Its :meth:`FrameSet.digest`
names its content in the evaluation cache.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from uav_depth.core.errors import FileFormatError
from uav_depth.core.session import FrameRecord, Session

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


class DiskFrames:
    """Frames of a log read from disk each time they are asked for (``frames``), never kept: what a worker
    needs for a frame set too large to hold (the safety sweep at a large rig) ships as paths. ``records``:
    (session directory, frame id) in order."""

    def __init__(self, name: str, records: Iterable[tuple[str, str]]):
        self.name = name
        self.records = tuple(records)

    def __len__(self) -> int:
        return len(self.records)

    @property
    def frames(self) -> tuple[FrameData, ...]:
        return tuple(load_frame(FrameRecord(Session(path), frame_id)) for path, frame_id in self.records)
