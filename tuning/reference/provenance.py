"""Where a reference disparity came from: the ``FRAMEID_ref.json`` file next to ``FRAMEID_ref.npy``.

Every reference this package writes is a float32 ``.npy`` in px of the left image
(NaN unknown, see :mod:`uav_depth.core.session`) with a JSON object beside it.
The one required key is ``kind``:

- ``import``: an existing map attached by ``uav-depth reference import``; keys
  ``source`` (absolute path), ``source_sha256``, ``format``, ``scale`` (stored value
  / scale = px) and ``check`` (the SGBM scale check, or null when skipped).
- ``onnx``: computed by ``uav-depth reference onnx``; keys ``model`` (absolute
  path), ``model_sha256``, ``provider`` (onnxruntime's name), ``onnxruntime``
  (version), ``inputs``, ``output``, ``normalize``, ``channel_order``,
  ``input_size`` [W, H] fed to the model, ``scaled_size`` [W, H] of the image area
  in it, ``fit`` and ``negated``.
- ``device``: the camera's own depth, logged by the OAK-D source (lower quality
  than a network); free-form keys such as ``device``.
- ``synthetic``: exact ray-cast disparity written by ``uav-depth synth``.

Writers also add ``created`` (UTC ISO 8601) and ``tool`` (``uav-depth X.Y.Z``).
Readers report ``unknown`` for a reference without a readable JSON file and
``none`` for a frame without a reference (the tuner then has only the
reference-free ``selfsup`` metric).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.session import FrameRecord, write_json

#: Kinds a reference file may record, best first. ``unknown``/``none`` are what readers report.
KINDS = ("synthetic", "import", "onnx", "device")
NO_REFERENCE = "none"
UNKNOWN = "unknown"
#: Keys that identify one source of references (frames sharing them came from the same place).
_SOURCE_KEYS = {"import": ("format", "scale"), "onnx": ("model", "model_sha256", "provider"),
                "device": ("device",), "synthetic": (), UNKNOWN: (), NO_REFERENCE: ()}


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def provenance_path(frame: FrameRecord) -> Path:
    return frame.session.frames_dir / f"{frame.frame_id}_ref.json"


def npy_path(frame: FrameRecord) -> Path:
    return frame.session.frames_dir / f"{frame.frame_id}_ref.npy"


def make_provenance(kind: str, **fields: Any) -> dict[str, Any]:
    """A provenance object with ``kind`` first, ``created`` and ``tool`` filled in."""
    if kind not in KINDS:
        raise ConfigError("reference kind", f"must be one of {', '.join(KINDS)}", kind)
    from uav_depth.core import __version__

    return {"kind": kind, **fields, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "tool": f"uav-depth {__version__}"}


def read_provenance(frame: FrameRecord) -> dict[str, Any]:
    """The frame's reference provenance: ``{"kind": "none"}`` without a reference,
    ``{"kind": "unknown", ...}`` when the JSON file is missing or unreadable."""
    if frame.ref_path is None:
        return {"kind": NO_REFERENCE}
    path = provenance_path(frame)
    if not path.exists():
        return {"kind": UNKNOWN, "note": f"{path.name} missing"}
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        return {"kind": UNKNOWN, "note": f"{path.name} unreadable ({exc})"}
    if not isinstance(doc, dict) or not isinstance(doc.get("kind"), str):
        return {"kind": UNKNOWN, "note": f"{path.name} has no 'kind'"}
    return doc


def describe(prov: Mapping[str, Any]) -> str:
    """One line for people: ``onnx raft.onnx (sha256 1a2b3c4d5e6f, cpu)``."""
    kind = prov.get("kind", UNKNOWN)
    if kind == "onnx":
        sha = str(prov.get("model_sha256", ""))[:12]
        return f"onnx {Path(str(prov.get('model', '?'))).name} (sha256 {sha}, {prov.get('provider', '?')})"
    if kind == "import":
        return f"import {prov.get('format', '?')} scale {prov.get('scale', '?')}"
    if kind == "device":
        return f"device {prov.get('device', '')} (camera depth: lower quality than a network)".replace("  ", " ")
    if kind == "synthetic":
        return "synthetic (exact ray-cast disparity)"
    if kind == NO_REFERENCE:
        return "none (only the reference-free selfsup metric applies)"
    return f"{kind} {prov.get('note', '')}".strip()


def describe_source(prov: Mapping[str, Any]) -> str:
    """:func:`describe` without what is particular to one frame (which file is missing): one line per source."""
    if prov.get("kind", UNKNOWN) == UNKNOWN:
        return "unknown (no readable provenance recorded)"
    return describe(prov)


def summarize_references(frames: Iterable[FrameRecord]) -> dict[str, Any]:
    """What a set of frames is measured against, for reports.

    Returns ``{"frames": N, "by_kind": {kind: count}, "sources": [{"kind", <source
    keys>, "frames": count, "description"}]}``; sources are grouped by the keys that
    identify them (an ONNX model by path, hash and provider).
    """
    by_kind: Counter[str] = Counter()
    sources: dict[tuple, dict[str, Any]] = {}
    n = 0
    for frame in frames:
        n += 1
        prov = read_provenance(frame)
        kind = str(prov.get("kind"))
        by_kind[kind] += 1
        keys = _SOURCE_KEYS.get(kind, ("note",))
        ident = (kind, *(json.dumps(prov.get(k), sort_keys=True, default=str) for k in keys))
        entry = sources.setdefault(ident, {"kind": kind, **{k: prov.get(k) for k in keys}, "frames": 0,
                                           "description": describe_source(prov)})
        entry["frames"] += 1
    return {"frames": n, "by_kind": dict(by_kind), "sources": list(sources.values())}


def has_reference_to_keep(frame: FrameRecord, overwrite: bool, replace_kinds: Iterable[str] = ()) -> bool:
    """True when ``frame`` already has a reference that must not be replaced.

    Resuming a batch skips such frames; ``overwrite`` replaces every reference,
    ``replace_kinds`` only those of the given kinds (e.g. ``device``).
    """
    if frame.ref_path is None or overwrite:
        return False
    return read_provenance(frame).get("kind") not in set(replace_kinds)


def write_reference(frame: FrameRecord, disparity: np.ndarray, provenance: Mapping[str, Any],
                    frame_shape: tuple[int, int] | None = None) -> Path:
    """Write ``FRAMEID_ref.npy`` (float32 px, NaN unknown) and its ``FRAMEID_ref.json``.

    The JSON goes first and the array last, each via a temporary file and a rename:
    the array is what marks a frame as done, so a killed batch never leaves an
    array without its provenance, and a half-written array is never visible.
    ``frame_shape`` (H, W) saves reading the left image again when the caller has it.
    """
    disp = np.asarray(disparity, dtype=np.float32)
    h, w = frame_shape or _frame_shape(frame)
    if disp.shape != (h, w):
        raise FileFormatError(f"{frame.key}: reference is {disp.shape[1]}x{disp.shape[0]} but the frame is "
                              f"{w}x{h} (W x H)")
    disp = np.where(np.isfinite(disp), disp, np.float32(np.nan)).astype(np.float32)
    write_json(provenance_path(frame), dict(provenance))
    target = npy_path(frame)
    tmp = target.with_name(f".{target.name}.tmp.npy")
    np.save(tmp, disp)
    os.replace(tmp, target)
    return target


def _frame_shape(frame: FrameRecord) -> tuple[int, int]:
    import cv2

    img = cv2.imread(str(frame.left_path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileFormatError(f"{frame.left_path}: missing or not a readable image")
    return int(img.shape[0]), int(img.shape[1])
