"""The log layout: the contract between the daemon's logger, ``synth``, the reference tools and the tuner.

A session directory::

    SESSION/
      calibration.yaml            # focal_px, baseline_m, width, height (full K/D/R/T when known)
      frames/
        000000_left.png
        000000_right.png
        000000_ref.npy            # optional reference disparity of the left image
        000000_ref.json           # optional: where the reference came from
        000000_meta.json          # optional: timestamp, truth, anything the writer knows

Reference maps may be ``.npy`` (float32 px, NaN unknown), ``.pfm`` (Middlebury /
Scene Flow, inf unknown) or 16-bit ``.png`` (KITTI, value/256, 0 unknown).
Commands that take a log directory accept a session or a directory of sessions.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from uav_depth.core.calibration import Calibration, load_calibration, save_calibration
from uav_depth.core.errors import FileFormatError, OutputExistsError
from uav_depth.core.fileio import read_text_file

CALIBRATION_FILE = "calibration.yaml"
FRAMES_DIR = "frames"
REF_SUFFIXES = (".npy", ".pfm", ".png")
_FRAME_RE = re.compile(r"^(?P<id>\d+)_left\.png$")


# -- disparity file formats --------------------------------------------------------------------

def read_pfm(path: Path) -> np.ndarray:
    """Read a PFM (Portable Float Map) as (H, W) float32 top row first."""
    with open(path, "rb") as fh:
        header = fh.readline().strip()
        if header not in (b"Pf", b"PF"):
            raise FileFormatError(f"{path}: not a PFM file (header {header[:8]!r})")
        dims = fh.readline().split()
        while not dims:
            dims = fh.readline().split()
        try:
            width, height = int(dims[0]), int(dims[1])
            scale = float(fh.readline().strip())
        except (ValueError, IndexError) as exc:
            raise FileFormatError(f"{path}: corrupt PFM header") from exc
        channels = 3 if header == b"PF" else 1
        data = np.fromfile(fh, dtype="<f4" if scale < 0 else ">f4")
    if data.size != width * height * channels:
        raise FileFormatError(f"{path}: PFM holds {data.size} values, expected {width * height * channels}")
    img = data.reshape(height, width, channels)[..., 0] if channels == 3 else data.reshape(height, width)
    return np.flipud(img).astype(np.float32)   # PFM stores the bottom row first


def write_pfm(path: Path, disp: np.ndarray) -> None:
    disp = np.asarray(disp, dtype="<f4")
    with open(path, "wb") as fh:
        fh.write(b"Pf\n%d %d\n-1.0\n" % (disp.shape[1], disp.shape[0]))
        np.flipud(disp).tofile(fh)


def read_disparity(path: str | os.PathLike[str], scale: float | None = None) -> np.ndarray:
    """Read a disparity map as (H, W) float32 px with NaN for unknown.

    ``.npy``: float px, NaN unknown. ``.pfm``: inf unknown. ``.png``: 16-bit KITTI
    style, value / ``scale`` (default 256), 0 unknown.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            disp = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise FileFormatError(f"{path}: not a readable .npy array ({exc})") from exc
        disp = np.asarray(disp, dtype=np.float32)
    elif suffix == ".pfm":
        disp = read_pfm(path)
    elif suffix == ".png":
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise FileFormatError(f"{path}: not a readable PNG")
        if raw.ndim != 2:
            raise FileFormatError(f"{path}: disparity PNG must have one channel, but has shape {raw.shape}")
        disp = raw.astype(np.float32) / np.float32(scale or 256.0)
        disp[raw == 0] = np.nan
        return disp
    else:
        raise FileFormatError(f"{path}: unknown disparity format {suffix!r} (expected .npy, .pfm or .png)")
    if disp.ndim != 2:
        raise FileFormatError(f"{path}: disparity must be 2-D, but has shape {disp.shape}")
    disp = disp.copy()
    disp[~np.isfinite(disp)] = np.nan
    return disp


def write_disparity(path: str | os.PathLike[str], disp: np.ndarray) -> Path:
    """Write a disparity map by suffix: .npy, .pfm, or a coloured .png for people."""
    path = Path(path)
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    disp = np.asarray(disp, dtype=np.float32)
    if suffix == ".npy":
        np.save(path, disp)
    elif suffix == ".pfm":
        write_pfm(path, np.where(np.isfinite(disp), disp, np.inf))
    elif suffix == ".png":
        if not cv2.imwrite(str(path), colourise(disp)):
            raise FileFormatError(f"{path}: could not write PNG")
    else:
        raise FileFormatError(f"{path}: unknown output format {suffix!r} (expected .npy, .pfm or .png)")
    return path


def colourise(disp: np.ndarray, max_disp: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of a disparity map (invalid pixels black)."""
    valid = np.isfinite(disp)
    top = max_disp or (float(np.nanmax(disp)) if valid.any() else 1.0)
    norm = np.zeros(disp.shape, np.uint8)
    norm[valid] = np.clip(disp[valid] / max(top, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(norm, cv2.COLORMAP_TURBO)
    out[~valid] = 0
    return out


# -- sessions ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class FrameRecord:
    """One logged frame of a session; images are read lazily."""

    session: "Session"
    frame_id: str

    @property
    def left_path(self) -> Path:
        return self.session.frames_dir / f"{self.frame_id}_left.png"

    @property
    def right_path(self) -> Path:
        return self.session.frames_dir / f"{self.frame_id}_right.png"

    @property
    def meta_path(self) -> Path:
        return self.session.frames_dir / f"{self.frame_id}_meta.json"

    @property
    def ref_path(self) -> Path | None:
        for suffix in REF_SUFFIXES:
            p = self.session.frames_dir / f"{self.frame_id}_ref{suffix}"
            if p.exists():
                return p
        return None

    @property
    def key(self) -> str:
        """Identifier unique across sessions: ``session_name/frame_id``."""
        return f"{self.session.path.name}/{self.frame_id}"

    def load_pair(self) -> tuple[np.ndarray, np.ndarray]:
        out = []
        for p in (self.left_path, self.right_path):
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise FileFormatError(f"{p}: missing or not a readable image")
            if img.ndim == 3 and img.shape[2] == 4:
                img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
            if img.dtype != np.uint8:
                raise FileFormatError(f"{p}: frames must be 8-bit, but got {img.dtype}")
            out.append(img)
        if out[0].shape != out[1].shape:
            raise FileFormatError(f"{self.key}: left {out[0].shape} and right {out[1].shape} differ in shape")
        return out[0], out[1]

    def load_reference(self) -> np.ndarray | None:
        p = self.ref_path
        return None if p is None else read_disparity(p)

    def load_meta(self) -> dict[str, Any]:
        if not self.meta_path.exists():
            return {}
        try:
            return json.loads(read_text_file(self.meta_path, "frame metadata"))
        except json.JSONDecodeError as exc:
            raise FileFormatError(f"{self.meta_path}: not valid JSON ({exc})") from exc


class Session:
    """A session directory in the log layout."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self.frames_dir = self.path / FRAMES_DIR

    @property
    def calibration_path(self) -> Path:
        return self.path / CALIBRATION_FILE

    def calibration(self) -> Calibration:
        return load_calibration(self.calibration_path)

    def frames(self) -> list[FrameRecord]:
        if not self.frames_dir.is_dir():
            return []
        ids = sorted(m.group("id") for m in (_FRAME_RE.match(p.name) for p in self.frames_dir.iterdir()) if m)
        return [FrameRecord(self, i) for i in ids]

    @staticmethod
    def is_session(path: Path) -> bool:
        return (path / FRAMES_DIR).is_dir() or (path / CALIBRATION_FILE).is_file()


def find_sessions(logdir: str | os.PathLike[str]) -> list[Session]:
    """A session, or every session directly inside a directory, sorted by name."""
    logdir = Path(logdir)
    if not logdir.is_dir():
        raise FileFormatError(f"{logdir}: log directory not found")
    if Session.is_session(logdir):
        return [Session(logdir)]
    sessions = [Session(p) for p in sorted(logdir.iterdir()) if p.is_dir() and Session.is_session(p)]
    if not sessions:
        raise FileFormatError(f"{logdir}: no session found (expected {FRAMES_DIR}/ and {CALIBRATION_FILE})")
    return sessions


def iter_frames(logdir: str | os.PathLike[str], require_reference: bool = False) -> Iterator[FrameRecord]:
    for session in find_sessions(logdir):
        for frame in session.frames():
            if require_reference and frame.ref_path is None:
                continue
            yield frame


def prepare_output(path: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Make ``path`` ready to receive a new session; OutputExistsError when that would destroy something.

    A missing or empty directory is fine. An existing session is refused unless ``overwrite``,
    and then removed first (so no frame or calibration of the old one is mixed into the new).
    A file, or a non-empty directory that is not a session, is always refused.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputExistsError(f"{p} is a file, not a session directory: choose another path")
    if p.is_dir() and any(p.iterdir()):
        if not Session.is_session(p):
            raise OutputExistsError(f"{p} is a non-empty directory that is not a session: choose another path")
        if not overwrite:
            raise OutputExistsError(f"{p} already holds a session ({len(Session(p).frames())} frames): "
                                    "pass --overwrite to replace it, or choose another path")
        shutil.rmtree(p)
    return p


class SessionWriter:
    """Writes frames into a session directory in the log layout.

    Each frame's files are written to temporary names and renamed, left image
    last, so a reader never sees a half-written frame.
    """

    def __init__(self, path: str | os.PathLike[str], calibration: Calibration):
        self.session = Session(path)
        self.session.frames_dir.mkdir(parents=True, exist_ok=True)
        if not self.session.calibration_path.exists():
            save_calibration(calibration, self.session.calibration_path)
        self.calibration = calibration

    def write(self, index: int, left: np.ndarray, right: np.ndarray, reference: np.ndarray | None = None,
              meta: dict[str, Any] | None = None, reference_source: dict[str, Any] | None = None) -> FrameRecord:
        frame = FrameRecord(self.session, f"{index:06d}")
        d = self.session.frames_dir
        if reference is not None:
            _atomic(d / f"{frame.frame_id}_ref.npy", lambda p: np.save(p, np.asarray(reference, np.float32)))
            if reference_source is not None:
                write_json(d / f"{frame.frame_id}_ref.json", reference_source)
        if meta is not None:
            write_json(frame.meta_path, meta)
        _atomic(frame.right_path, lambda p: _imwrite(p, right))
        _atomic(frame.left_path, lambda p: _imwrite(p, left))
        return frame


def _imwrite(path: Path, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise FileFormatError(f"{path}: could not encode PNG")
    with open(path, "wb") as fh:
        fh.write(buf.tobytes())


def _atomic(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.tmp{path.suffix}")
    write(tmp)
    os.replace(tmp, path)


def write_json(path: Path, obj: Any) -> None:
    _atomic(path, lambda p: p.write_text(json.dumps(obj, indent=1, default=_json_default)))


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


__all__ = ["Session", "SessionWriter", "FrameRecord", "find_sessions", "iter_frames", "read_disparity",
           "write_disparity", "colourise"]
