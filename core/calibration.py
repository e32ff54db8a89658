"""Stereo calibration: what turns disparity into metres (Z = f*B/d) and rectifies raw frames.

A calibration is either *rectified* (focal length, baseline and principal point of
an already-rectified pair) or *raw* (K, D of both cameras plus R, T between them,
from which OpenCV computes the rectification).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
from uav_depth.core.fileio import atomic_write_text
from uav_depth.core.yamlfile import load_yaml_file


@dataclass(frozen=True)
class Calibration:
    """Pinhole stereo calibration of the *rectified* left camera.

    ``focal_px`` and ``baseline_m`` give Z = focal_px * baseline_m / d. ``cx``/``cy``
    default to the image centre. When ``k_left`` etc. are set, frames are raw and
    must be rectified first (see :mod:`uav_depth.core.rectify`).
    """

    focal_px: float
    baseline_m: float
    width: int
    height: int
    cx: float | None = None
    cy: float | None = None
    k_left: tuple | None = None
    d_left: tuple | None = None
    k_right: tuple | None = None
    d_right: tuple | None = None
    r: tuple | None = None
    t: tuple | None = None
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False)

    @property
    def principal_point(self) -> tuple[float, float]:
        return (self.cx if self.cx is not None else (self.width - 1) / 2.0,
                self.cy if self.cy is not None else (self.height - 1) / 2.0)

    @property
    def is_raw(self) -> bool:
        return self.k_left is not None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"focal_px": float(self.focal_px), "baseline_m": float(self.baseline_m),
                               "width": int(self.width), "height": int(self.height)}
        for name in ("cx", "cy"):
            if getattr(self, name) is not None:
                out[name] = float(getattr(self, name))
        for name in ("k_left", "d_left", "k_right", "d_right", "r", "t"):
            v = getattr(self, name)
            if v is not None:
                out[name] = np.asarray(v, dtype=float).tolist()
        out.update(self.extra)
        return out


_REQUIRED = ("focal_px", "baseline_m", "width", "height")
_MATRICES = {"k_left": (3, 3), "d_left": None, "k_right": (3, 3), "d_right": None, "r": (3, 3), "t": (3,)}


def calibration_from_dict(data: Any, source: str | None = None) -> Calibration:
    """Validate a mapping into a :class:`Calibration`; errors name the key."""
    if not isinstance(data, Mapping):
        raise ConfigError("calibration", "must be a mapping", data, source)
    for key in _REQUIRED:
        if key not in data:
            raise ConfigError(f"calibration.{key}", "is required", None, source)
    kw: dict[str, Any] = {}
    for key in ("focal_px", "baseline_m"):
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise ConfigError(f"calibration.{key}", "must be a number greater than 0", v, source)
        kw[key] = float(v)
    for key in ("width", "height"):
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 16:
            raise ConfigError(f"calibration.{key}", "must be an integer of at least 16", v, source)
        kw[key] = v
    for key in ("cx", "cy"):
        if data.get(key) is not None:
            kw[key] = float(data[key])
    raw = [k for k in _MATRICES if data.get(k) is not None]
    if raw and len(raw) != len(_MATRICES):
        missing = sorted(set(_MATRICES) - set(raw))
        raise ConfigError("calibration", f"raw calibration needs all of {', '.join(_MATRICES)}",
                          f"missing {', '.join(missing)}", source)
    for key in raw:
        try:
            arr = np.asarray(data[key], dtype=float)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"calibration.{key}", "must be a numeric matrix", data[key], source) from exc
        shape = _MATRICES[key]
        if shape is not None and arr.shape != shape:
            raise ConfigError(f"calibration.{key}", f"must have shape {shape}", list(arr.shape), source)
        kw[key] = tuple(map(tuple, arr)) if arr.ndim == 2 else tuple(arr.ravel())
    extra = {k: v for k, v in data.items() if k not in kw and k not in _REQUIRED}
    return Calibration(**kw, extra=extra)


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    path = Path(path)
    try:
        data = load_yaml_file(path, "calibration file")
    except FileFormatError as exc:
        raise CalibrationError(str(exc)) from exc
    return calibration_from_dict(data, source=str(path))


def save_calibration(calib: Calibration, path: str | os.PathLike[str]) -> Path:
    return atomic_write_text(path, yaml.safe_dump(calib.to_dict(), sort_keys=False))
