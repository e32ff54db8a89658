"""Readers for foreign reference disparity files: one table, name -> format.

Every reader returns an (H, W) float32 disparity in px (stored value / ``scale``)
with NaN where unknown. The CLI's ``--format`` choices are this table's keys.

- ``npy``: float array in px, NaN/inf unknown (``scale`` default 1).
- ``pfm``: Portable Float Map (Middlebury 2014, Scene Flow), inf unknown (default 1).
- ``kitti-png``: 16-bit PNG, px = value / 256, 0 unknown (KITTI 2012/2015).
- ``middlebury-png``: 8- or 16-bit PNG, px = value / scale, 0 unknown. The scale
  depends on the dataset (Middlebury 2001/2003 store disparity x4 or x8 in 8-bit
  PNGs, so the full range fits), so pass ``scale``; the import's SGBM check flags a
  wrong one.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.session import read_pfm

from uav_depth.tuning.reference.options import FORMAT_INFO


@dataclass(frozen=True)
class ReferenceFormat:
    name: str
    suffix: str
    default_scale: float
    read_raw: Callable[[Path], np.ndarray]   # float32 stored values, NaN unknown
    doc: str

    def read(self, path: str | os.PathLike[str], scale: float | None = None) -> np.ndarray:
        """(H, W) float32 disparity in px, NaN unknown: stored value / scale."""
        s = self.default_scale if scale is None else check_scale(scale)
        raw = self.read_raw(Path(path))
        return (raw / np.float32(s)).astype(np.float32)


def check_scale(scale: float) -> float:
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ConfigError("--scale", "must be a positive number (stored value / scale = disparity in px)", scale)
    return float(scale)


def _finite(disp: np.ndarray, path: Path) -> np.ndarray:
    if disp.ndim != 2:
        raise FileFormatError(f"{path}: disparity must be 2-D, but has shape {disp.shape}")
    out = np.asarray(disp, dtype=np.float32).copy()
    out[~np.isfinite(out)] = np.nan
    return out


def _read_npy(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise FileFormatError(f"{path}: not a readable .npy array ({exc})") from exc
    if not np.issubdtype(arr.dtype, np.number):
        raise FileFormatError(f"{path}: .npy must hold numbers, but holds {arr.dtype}")
    return _finite(np.squeeze(arr) if arr.ndim > 2 else arr, path)


def _read_pfm(path: Path) -> np.ndarray:
    return _finite(read_pfm(path), path)


def _load_png(path: Path) -> np.ndarray:
    """The PNG's stored values, (H, W) uint8 or uint16."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise FileFormatError(f"{path}: missing or not a readable PNG")
    if raw.ndim == 3:
        # Some tools save grey maps as 3 identical channels; anything else is a picture, not data.
        if raw.shape[2] in (3, 4) and np.array_equal(raw[..., 0], raw[..., 1]) and np.array_equal(
                raw[..., 0], raw[..., 2]):
            raw = raw[..., 0]
        else:
            raise FileFormatError(f"{path}: disparity PNG must have one channel (or identical grey channels), "
                                  f"but has shape {raw.shape}: a coloured visualisation is not data")
    if raw.dtype not in (np.uint8, np.uint16):
        raise FileFormatError(f"{path}: disparity PNG must be 8- or 16-bit, but is {raw.dtype}")
    return raw


def _png_values(raw: np.ndarray) -> np.ndarray:
    out = raw.astype(np.float32)
    out[raw == 0] = np.nan   # both KITTI and Middlebury mark unknown with 0
    return out


def _read_middlebury_png(path: Path) -> np.ndarray:
    return _png_values(_load_png(path))


def _read_kitti_png(path: Path) -> np.ndarray:
    raw = _load_png(path)
    if raw.dtype != np.uint16:
        raise FileFormatError(f"{path}: KITTI disparity PNGs are 16-bit, but this one is 8-bit "
                              f"(a Middlebury-style map? use --format middlebury-png --scale S)")
    return _png_values(raw)


_READERS = {"npy": _read_npy, "pfm": _read_pfm, "kitti-png": _read_kitti_png, "middlebury-png": _read_middlebury_png}
FORMATS: dict[str, ReferenceFormat] = {name: ReferenceFormat(name, suffix, scale, _READERS[name], doc)
                                       for name, (suffix, scale, doc) in FORMAT_INFO.items()}


def format_for(name: str | None, pattern: str) -> ReferenceFormat:
    """The format named, or the one the pattern's suffix implies (.npy, .pfm); npy when neither is given."""
    if name is None and not pattern:
        return FORMATS["npy"]
    if name is not None:
        if name not in FORMATS:
            raise ConfigError("--format", f"must be one of {', '.join(FORMATS)}", name)
        return FORMATS[name]
    suffix = Path(pattern).suffix.lower()
    by_suffix = [f for f in FORMATS.values() if f.suffix == suffix]
    if len(by_suffix) == 1:
        return by_suffix[0]
    if len(by_suffix) > 1:
        raise ConfigError("--format", f"must be given for {suffix} files (one of "
                          f"{', '.join(f.name for f in by_suffix)})", None)
    raise ConfigError("--format", f"must be given unless the pattern ends in .npy or .pfm (one of "
                      f"{', '.join(FORMATS)})", None)
