"""Frame sources: one name -> factory table; the CLI's choices come from its keys.

Each source module defines a frozen ``Config`` (``KIND``, ``KEYS``, ``from_dict``)
and a source class built from it. Hardware modules import their drivers (depthai,
V4L2 through OpenCV) only when a source is opened, so listing and validating
never needs the hardware or the extra.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Mapping

from ..errors import ConfigError
from .base import EndOfStream, Frame, FrameSource

#: kind -> (module, source class, one-line help)
SOURCES: dict[str, tuple[str, str, str]] = {
    "synthetic": ("uav_depth.daemon.sources.synthetic", "SyntheticSource",
                  "ray-cast tree scene with a branch at a known distance, optionally moving (no hardware)"),
    "replay": ("uav_depth.daemon.sources.replay", "ReplaySource",
               "a logged session (log layout), paced at its timestamps or a chosen rate, optionally looping"),
    "uvc": ("uav_depth.daemon.sources.uvc", "UvcSource",
            "a ZED Mini (side-by-side over UVC/V4L2) or two V4L2 cameras"),
    "oak": ("uav_depth.daemon.sources.oak", "OakSource",
            "a Luxonis OAK-D through depthai 3.x: rectified left/right, optionally the device's depth"),
}


def _module(kind: str):
    return importlib.import_module(SOURCES[kind][0])


def source_keys(kind: str):
    """The :class:`~uav_depth.daemon.config.Key` table of a source kind."""
    return _module(kind).Config.KEYS


def source_config_from_dict(data: Any, source: str | None = None, base_dir: Path | None = None,
                            origin: Mapping[str, str] | None = None) -> Any:
    """Validate the ``source:`` section into the kind's frozen config."""
    origin = origin or {}
    if not isinstance(data, Mapping):
        raise ConfigError("source", "must be a mapping with kind: " + ", ".join(SOURCES), data,
                          origin.get("source", source))
    kind = data.get("kind")
    if kind not in SOURCES:
        raise ConfigError("source.kind", f"must be one of {', '.join(SOURCES)}", kind,
                          origin.get("source.kind", source))
    options = {k: v for k, v in data.items() if k != "kind"}
    return _module(kind).Config.from_dict(options, source, base_dir, origin)


def create_source(config: Any, **kwargs: Any) -> FrameSource:
    """Build (not open) the source for a validated source config."""
    module, cls, _ = SOURCES[config.KIND]
    return getattr(importlib.import_module(module), cls)(config, **kwargs)


__all__ = ["SOURCES", "Frame", "FrameSource", "EndOfStream", "create_source", "source_config_from_dict",
           "source_keys"]
