"""Reference disparity from a user-supplied ONNX stereo network, run with onnxruntime.

Public RAFT-Stereo, CREStereo and HITNet exports take a left and a right image and
return a disparity map. What we accept (checked before any frame is touched):

- inputs: two image tensors ``[1, 3, H, W]`` (or ``[1, 1, H, W]`` grey), float32 or
  float16; named ``*left*``/``*right*`` or else taken in order (first = left); or
  one ``[1, 6, H, W]`` (or ``[1, 2, H, W]``) tensor with left and right stacked on
  the channel axis (HITNet exports).
- output: ``[1, 1, H, W]``, ``[1, H, W]``, or ``[1, 2, H, W]`` flow (channel 0 is
  the x-displacement, CREStereo), at the input's resolution, in px of the input.
  Flow-style outputs are negative (RAFT-Stereo returns -disparity): ``sign``
  ``auto`` negates a map whose median is negative and records that it did.

Geometry: the frame is brought to the model's input size (the fixed size in the
model, ``input_size``, or for a model with free H/W the frame rounded up to a
multiple of ``pad_multiple``) by ``letterbox`` (scale to fit keeping the aspect
ratio, replicate-pad right/bottom), ``stretch`` or ``pad`` (no scaling). The
output is cropped to the image area, resized back to the frame and multiplied by
frame width / scaled width: disparity is in px of the frame's left image.

The model's signature (what it must look like) is checked by :mod:`.signature`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import cv2
import numpy as np

from uav_depth.core.errors import ConfigError, DependencyError, FileFormatError, FrameError
from uav_depth.core.session import FrameRecord, iter_frames

from uav_depth.tuning.reference.options import CHANNEL_ORDERS, FITS, NORMALIZATIONS, PROVIDERS, SIGNS
from uav_depth.tuning.reference.provenance import has_reference_to_keep, make_provenance, sha256_file, write_reference
from uav_depth.tuning.reference.signature import TensorInfo, parse_signature

_IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], np.float32)  # RGB
_IMAGENET_STD = np.array([0.229, 0.224, 0.225], np.float32)


@dataclass(frozen=True)
class Geometry:
    """How one frame size maps to the model input: scaled size, then padding to (width, height)."""

    frame_w: int
    frame_h: int
    width: int          # model input, px
    height: int
    scaled_w: int       # image area inside the input, px
    scaled_h: int

    @property
    def disparity_factor(self) -> float:
        """Multiply model-px disparity by this to get frame px (x scale only matters)."""
        return self.frame_w / self.scaled_w


def plan_geometry(frame_w: int, frame_h: int, width: int, height: int, fit: str) -> Geometry:
    if fit == "stretch":
        return Geometry(frame_w, frame_h, width, height, width, height)
    if fit == "pad":
        if frame_w > width or frame_h > height:
            raise ConfigError("--fit", f"pad needs the frame ({frame_w}x{frame_h}) to fit in the model input "
                              f"({width}x{height}); use letterbox or stretch", fit)
        return Geometry(frame_w, frame_h, width, height, frame_w, frame_h)
    s = min(width / frame_w, height / frame_h)
    sw, sh = min(width, max(1, round(frame_w * s))), min(height, max(1, round(frame_h * s)))
    return Geometry(frame_w, frame_h, width, height, sw, sh)


@dataclass(frozen=True)
class OnnxConfig:
    """Validated settings of ``uav-depth reference onnx``.

    ``input_size``: (W, H) fed to the model; required to match a model's fixed
    size, and the size used for a model with free H/W (default: the frame rounded
    up to ``pad_multiple``). ``fit``: letterbox, stretch or pad (default: pad for a
    free-size model without ``input_size``, else letterbox).
    """

    model: Path
    provider: str = "cpu"
    input_size: tuple[int, int] | None = None
    fit: str | None = None
    normalize: str = "none"
    channel_order: str = "rgb"
    sign: str = "auto"
    output: str | None = None
    pad_multiple: int = 32
    overwrite: bool = False
    replace_kinds: tuple[str, ...] = ()
    threads: int = 0
    model_sha256: str = field(init=False, default="")

    def __post_init__(self) -> None:
        object.__setattr__(self, "model", Path(self.model))
        if not self.model.is_file():
            raise FileFormatError(f"{self.model}: model file not found")
        checks = (("--provider", self.provider, tuple(PROVIDERS)), ("--normalize", self.normalize,
                  tuple(NORMALIZATIONS)), ("--channel-order", self.channel_order, CHANNEL_ORDERS),
                  ("--sign", self.sign, SIGNS))
        for key, value, choices in checks:
            if value not in choices:
                raise ConfigError(key, f"must be one of {', '.join(choices)}", value)
        if self.fit is not None and self.fit not in FITS:
            raise ConfigError("--fit", f"must be one of {', '.join(FITS)}", self.fit)
        if self.input_size is not None:
            w, h = self.input_size
            if not (isinstance(w, int) and isinstance(h, int) and w >= 8 and h >= 8):
                raise ConfigError("--input-size", "must be WxH with W and H at least 8 px", self.input_size)
        if not (isinstance(self.pad_multiple, int) and self.pad_multiple >= 1):
            raise ConfigError("--pad-multiple", "must be a positive integer", self.pad_multiple)
        if self.threads < 0:
            raise ConfigError("--threads", "must be 0 (onnxruntime's default) or more", self.threads)
        object.__setattr__(self, "model_sha256", sha256_file(self.model))


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise ConfigError("--input-size", "must be WxH in px, like 640x480", text) from exc
    return w, h


def _ort():
    try:
        import onnxruntime
    except ImportError as exc:
        raise DependencyError("onnxruntime", "onnx", "reference disparity from an ONNX network") from exc
    return onnxruntime


def _ort_errors() -> tuple[type[BaseException], ...]:
    from onnxruntime.capi import onnxruntime_pybind11_state as state

    return (RuntimeError, *(c for c in vars(state).values() if isinstance(c, type) and issubclass(c, Exception)))


class StereoNetwork:
    """An ONNX stereo model loaded with onnxruntime, checked to look like a stereo network."""

    def __init__(self, cfg: OnnxConfig):
        ort = _ort()
        self.cfg = cfg
        wanted = PROVIDERS[cfg.provider]
        available = ort.get_available_providers()
        if wanted[0] not in available:
            raise ConfigError("--provider", f"must be available in this onnxruntime (available: "
                              f"{', '.join(available)}; cuda needs the onnxruntime-gpu package)", cfg.provider)
        opts = ort.SessionOptions()
        opts.log_severity_level = 3   # onnxruntime's warnings are for model authors, not users
        if cfg.threads:
            opts.intra_op_num_threads = cfg.threads
        try:
            self.session = ort.InferenceSession(str(cfg.model), opts, providers=[p for p in wanted if p in available])
        except _ort_errors() as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise FileFormatError(f"{cfg.model}: onnxruntime cannot load this model ({first})") from exc
        ins = [TensorInfo.from_node_arg(a) for a in self.session.get_inputs()]
        outs = [TensorInfo.from_node_arg(a) for a in self.session.get_outputs()]
        self.signature = parse_signature(ins, outs, str(cfg.model), cfg.output)
        sig = self.signature
        if cfg.input_size is not None and sig.width is not None and sig.height is not None \
                and cfg.input_size != (sig.width, sig.height):
            raise ConfigError("--input-size", f"must match the model's fixed input size {sig.width}x{sig.height}",
                              f"{cfg.input_size[0]}x{cfg.input_size[1]}")
        self.provider = self.session.get_providers()[0]
        self.onnxruntime_version = ort.__version__
        self._negate: bool | None = {"auto": None, "positive": False, "negative": True}[cfg.sign]

    def geometry(self, frame_w: int, frame_h: int) -> tuple[Geometry, str]:
        """Geometry for a frame size and the fit actually used."""
        sig, cfg = self.signature, self.cfg
        free = sig.width is None or sig.height is None
        if cfg.input_size is not None:
            w, h = cfg.input_size
        elif not free:
            w, h = sig.width, sig.height
        else:
            m = cfg.pad_multiple
            w, h = m * math.ceil(frame_w / m), m * math.ceil(frame_h / m)
        w = sig.width or w
        h = sig.height or h
        fit = cfg.fit or ("pad" if free and cfg.input_size is None else "letterbox")
        return plan_geometry(frame_w, frame_h, w, h, fit), fit

    def _prepare(self, img: np.ndarray, geo: Geometry) -> np.ndarray:
        """uint8 grey/BGR (H, W[, 3]) -> (1, C, h, w) model input."""
        sig, cfg = self.signature, self.cfg
        if sig.channels == 1:
            x = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        else:
            x = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img
            if cfg.channel_order == "rgb":
                x = cv2.cvtColor(x, cv2.COLOR_BGR2RGB)
        if (geo.scaled_w, geo.scaled_h) != (geo.frame_w, geo.frame_h):
            shrink = geo.scaled_w < geo.frame_w
            x = cv2.resize(x, (geo.scaled_w, geo.scaled_h), interpolation=cv2.INTER_AREA if shrink else
                           cv2.INTER_LINEAR)
        pad_r, pad_b = geo.width - geo.scaled_w, geo.height - geo.scaled_h
        if pad_r or pad_b:
            # Replicate, as RAFT-Stereo's InputPadder does: a black band would be matched too.
            x = cv2.copyMakeBorder(x, 0, pad_b, 0, pad_r, cv2.BORDER_REPLICATE)
        x = x.astype(np.float32)
        if x.ndim == 2:
            x = x[..., None]
        x = _normalize(x, cfg.normalize, cfg.channel_order)
        return np.ascontiguousarray(x.transpose(2, 0, 1)[None]).astype(sig.dtype)

    def predict(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """(H, W) float32 disparity in px of the frame's left image (NaN unknown), and how it was made."""
        h, w = left.shape[:2]
        geo, fit = self.geometry(w, h)
        sig = self.signature
        a, b = self._prepare(left, geo), self._prepare(right, geo)
        feeds = {sig.inputs[0]: np.concatenate([a, b], axis=1)} if sig.stacked else {sig.inputs[0]: a,
                                                                                    sig.inputs[1]: b}
        try:
            (raw,) = self.session.run([sig.output], feeds)
        except _ort_errors() as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise FrameError(f"{self.cfg.model}: inference failed on a {geo.width}x{geo.height} input ({first})") \
                from exc
        out = np.asarray(raw, dtype=np.float32)
        out = out[0, 0] if out.ndim == 4 else out[0] if out.ndim == 3 else out
        if out.shape != (geo.height, geo.width):
            raise FrameError(f"{self.cfg.model}: output {sig.output!r} is {out.shape[1]}x{out.shape[0]} but the "
                             f"input was {geo.width}x{geo.height}: expected a full-resolution disparity")
        out = out[:geo.scaled_h, :geo.scaled_w]
        if self._negate is None:
            finite = out[np.isfinite(out)]
            # Flow-style networks (RAFT-Stereo) return x-displacement = -disparity.
            self._negate = bool(finite.size and np.median(finite) < 0)
        if self._negate:
            out = -out
        if (geo.scaled_w, geo.scaled_h) != (w, h):
            out = cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
        out = (out * np.float32(geo.disparity_factor)).astype(np.float32)
        out[~np.isfinite(out)] = np.nan
        info = {"input_size": [geo.width, geo.height], "scaled_size": [geo.scaled_w, geo.scaled_h], "fit": fit,
                "negated": self._negate}
        return out, info

    def provenance(self, info: dict[str, Any]) -> dict[str, Any]:
        cfg, sig = self.cfg, self.signature
        return make_provenance(
            "onnx", model=str(cfg.model.resolve()), model_sha256=cfg.model_sha256, provider=self.provider,
            onnxruntime=self.onnxruntime_version, inputs=list(sig.inputs), output=sig.output,
            normalize=cfg.normalize, channel_order=cfg.channel_order if sig.channels == 3 else "grey", **info)


def _normalize(x: np.ndarray, how: str, channel_order: str) -> np.ndarray:
    if how == "none":
        return x
    if how == "unit":
        return x * np.float32(1.0 / 255.0)
    if how == "signed":
        return x * np.float32(1.0 / 127.5) - np.float32(1.0)
    x = x * np.float32(1.0 / 255.0)
    mean, std = (_IMAGENET_MEAN, _IMAGENET_STD) if channel_order == "rgb" else (_IMAGENET_MEAN[::-1],
                                                                               _IMAGENET_STD[::-1])
    if x.shape[2] == 1:   # grey model: the channels' average statistics
        mean, std = mean.mean(keepdims=True), std.mean(keepdims=True)
    return (x - mean) / std


@dataclass(frozen=True)
class OnnxResult:
    written: tuple[str, ...]
    skipped: tuple[str, ...]


def run_onnx_references(logdir: str | os.PathLike[str], cfg: OnnxConfig,
                        progress: Callable[[Iterable, int], Iterable] | None = None,
                        network: StereoNetwork | None = None) -> OnnxResult:
    """Compute a reference for every frame of ``logdir`` that has none (all with ``overwrite``).

    The model is loaded and checked before any frame is read. Each finished frame
    is written at once (``FRAMEID_ref.npy`` + ``FRAMEID_ref.json``), so an
    interrupted run keeps its work and the next run resumes where it stopped.
    ``progress(iterable, total)`` wraps the loop (a tqdm bar in the CLI).
    """
    net = network or StereoNetwork(cfg)
    frames = list(iter_frames(logdir))
    keep = {f.key for f in frames if has_reference_to_keep(f, cfg.overwrite, cfg.replace_kinds)}
    todo = [f for f in frames if f.key not in keep]
    skipped = tuple(f.key for f in frames if f.key in keep)
    written = []
    iterator: Iterable[FrameRecord] = progress(todo, len(todo)) if progress is not None else todo
    for frame in iterator:
        left, right = frame.load_pair()
        disp, info = net.predict(left, right)
        write_reference(frame, disp, net.provenance(info), frame_shape=left.shape[:2])
        written.append(frame.key)
    return OnnxResult(tuple(written), skipped)
