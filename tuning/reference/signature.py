"""What a stereo ONNX model must look like, checked before any frame is touched.

Accepted (``parse_signature``):

- inputs: two image tensors ``[1, 3, H, W]`` (or ``[1, 1, H, W]`` grey), float32 or
  float16; named ``*left*``/``*right*`` or else taken in order (first = left); or
  one ``[1, 6, H, W]`` (or ``[1, 2, H, W]``) tensor with left and right stacked on
  the channel axis (HITNet exports).
- output: ``[1, 1, H, W]``, ``[1, H, W]``, or ``[1, 2, H, W]`` flow (channel 0 is
  the x-displacement, CREStereo), at the input's resolution, in px of the input.

A model that does not match is refused with one ConfigError naming what was expected and what it has.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from uav_depth.core.errors import ConfigError

EXPECTED = ("a stereo network: inputs left and right [1,3,H,W] (or [1,1,H,W]) float32, or one [1,6,H,W] input "
            "with left and right stacked; output disparity [1,1,H,W] or [1,H,W] (or [1,2,H,W] flow)")
_DTYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16}


@dataclass(frozen=True)
class TensorInfo:
    """Name, shape (ints, or None for a free dimension) and onnxruntime type string."""

    name: str
    shape: tuple[int | None, ...]
    type: str

    @classmethod
    def from_node_arg(cls, arg: Any) -> "TensorInfo":
        shape = tuple(d if isinstance(d, int) and d > 0 else None for d in (arg.shape or ()))
        return cls(arg.name, shape, arg.type)

    def __str__(self) -> str:
        dims = ",".join("?" if d is None else str(d) for d in self.shape)
        return f"{self.name}[{dims}] {self.type.replace('tensor(', '').rstrip(')')}"


@dataclass(frozen=True)
class StereoSignature:
    """How to feed a model and read its disparity.

    ``inputs``: (left name, right name), or (stacked name,) for one input with left
    and right on the channel axis. ``channels``: 1 or 3 per image. ``height``/
    ``width``: the model's fixed input size, None where free. ``flow``: output has
    two channels, channel 0 is used.
    """

    inputs: tuple[str, ...]
    channels: int
    dtype: type
    height: int | None
    width: int | None
    output: str
    flow: bool

    @property
    def stacked(self) -> bool:
        return len(self.inputs) == 1


def _bad(model: str, why: str, inputs: Sequence[TensorInfo], outputs: Sequence[TensorInfo]) -> ConfigError:
    got = f"inputs {', '.join(map(str, inputs)) or '(none)'}; outputs {', '.join(map(str, outputs)) or '(none)'}"
    return ConfigError("--model", f"must be {EXPECTED} ({why})", f"{model}: {got}")


def parse_signature(inputs: Sequence[TensorInfo], outputs: Sequence[TensorInfo], model: str = "model",
                    output: str | None = None) -> StereoSignature:
    """Check that a model looks like a stereo network; raise ConfigError naming what was expected."""
    def bad(why: str) -> ConfigError:
        return _bad(model, why, inputs, outputs)

    if len(inputs) not in (1, 2):
        raise bad(f"it has {len(inputs)} inputs, expected 2 (left, right) or 1 stacked")
    for t in inputs:
        if len(t.shape) != 4:
            raise bad(f"input {t.name!r} has rank {len(t.shape)}, expected rank 4 [N,C,H,W]")
        if t.type not in _DTYPES:
            raise bad(f"input {t.name!r} is {t.type}, expected float32 or float16")
        if t.shape[0] not in (1, None):
            raise bad(f"input {t.name!r} has batch size {t.shape[0]}, expected 1")
    if len(inputs) == 2:
        a, b = inputs
        if a.shape != b.shape or a.type != b.type:
            raise bad(f"inputs {a.name!r} and {b.name!r} differ in shape or type")
        ch = a.shape[1] if a.shape[1] is not None else 3
        if ch not in (1, 3):
            raise bad(f"input {a.name!r} has {ch} channels, expected 3 (or 1)")
        names = [t.name.lower() for t in inputs]
        # Name the sides when the exporter did; otherwise the usual (left, right) order.
        if "right" in names[0] and "left" in names[1]:
            order = (b.name, a.name)
        else:
            order = (a.name, b.name)
    else:
        a = inputs[0]
        if a.shape[1] not in (2, 6):
            raise bad(f"single input {a.name!r} has {a.shape[1]} channels, expected 6 (or 2): left and right stacked")
        ch = a.shape[1] // 2
        order = (a.name,)
    h, w = a.shape[2], a.shape[3]

    def disparity_like(t: TensorInfo) -> bool:
        if len(t.shape) == 3:
            return t.shape[0] in (1, None)
        return len(t.shape) == 4 and t.shape[0] in (1, None) and t.shape[1] in (1, 2, None)

    if output is not None:
        chosen = [t for t in outputs if t.name == output]
        if not chosen:
            raise ConfigError("--output", f"must name an output of the model ({', '.join(t.name for t in outputs)})",
                              output)
        if not disparity_like(chosen[0]):
            raise bad(f"output {output!r} has shape {chosen[0].shape}, expected [1,1,H,W], [1,H,W] or [1,2,H,W]")
    else:
        chosen = [t for t in outputs if disparity_like(t)]
        if not chosen:
            ranks = ", ".join(f"{t.name!r} rank {len(t.shape)}" for t in outputs)
            raise bad(f"no output looks like a disparity map ({ranks})")
        if len(chosen) > 1:
            same = [t for t in chosen if t.shape[-2:] == (h, w) and h is not None]
            if len(same) != 1:
                raise ConfigError("--output", "must choose one of the model's disparity-like outputs "
                                  f"({', '.join(t.name for t in chosen)})", None)
            chosen = same
    out = chosen[0]
    if out.type not in _DTYPES:
        raise bad(f"output {out.name!r} is {out.type}, expected float32 or float16")
    flow = len(out.shape) == 4 and out.shape[1] == 2
    return StereoSignature(order, ch, _DTYPES[a.type], h, w, out.name, flow)
