"""Attach existing reference maps (any tool, a LiDAR projection, a public dataset) to logged frames.

Files are matched to frames by a pattern with ``{id}`` (the frame id, ``000000``),
``{index}`` (the same as an integer, so ``{index:04d}`` works) and ``{session}``
(the session directory's name). Each map is read with its format and scale,
checked against the frame's size, and written as ``FRAMEID_ref.npy`` with a
``kind: import`` provenance. Before anything is written, a sample SGBM run flags a
reference in the wrong unit (:mod:`.check`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.session import FrameRecord, find_sessions

from uav_depth.tuning.reference.check import RATIO_TOLERANCE, ScaleCheck, check_reference_scale
from uav_depth.tuning.reference.formats import ReferenceFormat, check_scale, format_for
from uav_depth.tuning.reference.provenance import has_reference_to_keep, make_provenance, sha256_file, write_reference


@dataclass(frozen=True)
class ImportConfig:
    """How to find and read the reference files.

    ``format`` defaults to the pattern's suffix (.npy, .pfm), or npy without a
    pattern; ``pattern`` defaults to ``{id}`` + the format's suffix. ``scale``: stored value
    / scale = px (default: the format's). ``check``: run the SGBM scale check on up
    to ``check_frames`` frames; ``tolerance``: the ratio it accepts either way.
    """

    source_dir: Path
    format: str | None = None
    pattern: str | None = None
    scale: float | None = None
    overwrite: bool = False
    replace_kinds: tuple[str, ...] = ()
    check: bool = True
    check_frames: int = 3
    tolerance: float = RATIO_TOLERANCE
    fmt: ReferenceFormat = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "source_dir", Path(self.source_dir))
        if not self.source_dir.is_dir():
            raise ConfigError("--from", "must be an existing directory", str(self.source_dir))
        fmt = format_for(self.format, self.pattern or "")
        object.__setattr__(self, "fmt", fmt)
        if self.pattern is None:
            object.__setattr__(self, "pattern", "{id}" + fmt.suffix)
        if self.scale is not None:
            object.__setattr__(self, "scale", check_scale(self.scale))
        if self.check_frames < 1:
            raise ConfigError("--check-frames", "must be at least 1", self.check_frames)
        if not self.tolerance > 1.0:
            raise ConfigError("--tolerance", "must be greater than 1", self.tolerance)

    @property
    def effective_scale(self) -> float:
        return self.fmt.default_scale if self.scale is None else float(self.scale)

    def source_for(self, frame: FrameRecord) -> Path:
        try:
            name = self.pattern.format(id=frame.frame_id, index=int(frame.frame_id), session=frame.session.path.name)
        except (KeyError, IndexError, ValueError) as exc:
            raise ConfigError("--pattern", "may only use the fields {id}, {index} and {session}",
                              self.pattern) from exc
        return self.source_dir / name


@dataclass(frozen=True)
class ImportResult:
    written: tuple[str, ...]
    skipped: tuple[str, ...]      # already had a reference to keep
    missing: tuple[str, ...]      # no source file matched
    check: ScaleCheck | None


def _frames(logdir: str | os.PathLike[str], cfg: ImportConfig) -> list[FrameRecord]:
    sessions = find_sessions(logdir)
    if len(sessions) > 1 and "{session" not in cfg.pattern:
        raise ConfigError("--pattern", f"must contain {{session}} when the log has {len(sessions)} sessions "
                          "(frame ids repeat across sessions)", cfg.pattern)
    return [f for s in sessions for f in s.frames()]


def _read(frame: FrameRecord, path: Path, cfg: ImportConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    left, right = frame.load_pair()
    ref = cfg.fmt.read(path, cfg.scale)
    if ref.shape != left.shape[:2]:
        raise FileFormatError(f"{path}: reference is {ref.shape[1]}x{ref.shape[0]} but frame {frame.key} is "
                              f"{left.shape[1]}x{left.shape[0]} (W x H): references must be in the frame's pixels")
    return left, right, ref


def import_references(logdir: str | os.PathLike[str], cfg: ImportConfig,
                      progress: Callable[[Iterable], Iterable] | None = None) -> ImportResult:
    """Import references for every frame of ``logdir`` that has a matching file.

    Frames that already have a reference are skipped (resume) unless
    ``cfg.overwrite`` or their kind is in ``cfg.replace_kinds``. Raises ConfigError
    when the scale check flags the references; nothing is written then.
    """
    frames = _frames(logdir, cfg)
    todo, skipped, missing = [], [], []
    for frame in frames:
        if has_reference_to_keep(frame, cfg.overwrite, cfg.replace_kinds):
            skipped.append(frame.key)
            continue
        src = cfg.source_for(frame)
        (todo if src.is_file() else missing).append((frame, src))
    missing_keys = tuple(f.key for f, _ in missing)
    if not todo:
        if skipped:
            return ImportResult((), tuple(skipped), missing_keys, None)
        example = missing[0][1] if missing else cfg.source_dir / cfg.pattern
        raise FileFormatError(f"{cfg.source_dir}: no reference file matches a frame (looked for {example})")

    check = None
    if cfg.check:
        picks = np.unique(np.linspace(0, len(todo) - 1, min(cfg.check_frames, len(todo))).round().astype(int))
        samples = [(todo[i][0].key, *_read(todo[i][0], todo[i][1], cfg)) for i in picks]
        check = check_reference_scale(samples, cfg.effective_scale, cfg.tolerance)
        if check.ok is False:
            raise ConfigError("--scale", f"must make the reference agree with SGBM ({check.reason}; "
                              "--no-check imports anyway)", cfg.effective_scale)

    written = []
    iterator = progress(todo) if progress is not None else todo
    for frame, src in iterator:
        left, _, ref = _read(frame, src, cfg)
        prov = make_provenance("import", source=str(src.resolve()), source_sha256=sha256_file(src),
                               format=cfg.fmt.name, scale=cfg.effective_scale,
                               check=None if check is None else check.as_dict())
        write_reference(frame, ref, prov, frame_shape=left.shape[:2])
        written.append(frame.key)
    return ImportResult(tuple(written), tuple(skipped), missing_keys, check)
