"""The choices of ``uav-depth reference``, in one light module (no numpy/OpenCV) so ``--help`` stays fast.

formats.py and network.py build on these tables; the CLI's choices are their keys.
"""

from __future__ import annotations

#: format name -> (file suffix, default scale, description). Stored value / scale = px.
FORMAT_INFO: dict[str, tuple[str, float, str]] = {
    "npy": (".npy", 1.0, "float array, px, NaN/inf unknown"),
    "pfm": (".pfm", 1.0, "Portable Float Map (Middlebury 2014, Scene Flow), inf unknown"),
    "kitti-png": (".png", 256.0, "16-bit PNG, value/256 px, 0 unknown"),
    "middlebury-png": (".png", 1.0, "8/16-bit PNG, value/scale px, 0 unknown (pass --scale: x4, x8 ...)"),
}

#: --provider name -> onnxruntime provider names, in preference order.
PROVIDERS = {"cpu": ("CPUExecutionProvider",), "cuda": ("CUDAExecutionProvider", "CPUExecutionProvider")}
FITS = ("letterbox", "stretch", "pad")
SIGNS = ("auto", "positive", "negative")
CHANNEL_ORDERS = ("rgb", "bgr")
#: name -> what it does to 0..255 pixel values. RAFT-Stereo and CREStereo exports
#: take raw 0..255 (they normalise inside); HITNet exports take 0..1.
NORMALIZATIONS = {
    "none": "raw 0..255",
    "unit": "x / 255 (0..1)",
    "signed": "x / 127.5 - 1 (-1..1)",
    "imagenet": "(x / 255 - ImageNet mean) / ImageNet std, per RGB channel",
}
