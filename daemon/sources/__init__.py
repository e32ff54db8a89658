"""Frame sources: one name -> factory table; the CLI's choices come from its keys.

Each source module defines a frozen ``Config`` (``KIND``, ``SOURCE_CLASS``,
``KEYS``, ``from_dict``) and a source class built from it. Hardware modules import
their drivers (depthai, V4L2 through OpenCV) only when a source is opened, so
listing and validating never needs the hardware or the extra.

:data:`BUILTIN` holds what flies: real cameras and replay. A table with more
kinds (the simulator's synthetic source) is composed above the runtime, by the
CLI, and handed to the config loader; the runtime never imports the simulator.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Mapping

from uav_depth.core.errors import ConfigError
from uav_depth.core.frames import EndOfStream, Frame, FrameSource

#: kind -> (module, source class, one-line help)
SourceTable = Mapping[str, tuple[str, str, str]]

#: The sources of the on-board runtime.
BUILTIN: dict[str, tuple[str, str, str]] = {
    "replay": ("uav_depth.daemon.sources.replay", "ReplaySource",
               "a logged session (log layout), paced at its timestamps or a chosen rate, optionally looping"),
    "uvc": ("uav_depth.daemon.sources.uvc", "UvcSource",
            "a ZED Mini (side-by-side over UVC/V4L2) or two V4L2 cameras"),
    "oak": ("uav_depth.daemon.sources.oak", "OakSource",
            "a Luxonis OAK-D through depthai 3.x: rectified left/right, optionally the device's depth"),
}


def source_keys(kind: str, sources: SourceTable = BUILTIN):
    """The :class:`~uav_depth.core.keys.Key` table of a source kind."""
    return importlib.import_module(sources[kind][0]).Config.KEYS


def source_config_from_dict(data: Any, source: str | None = None, base_dir: Path | None = None,
                            origin: Mapping[str, str] | None = None, sources: SourceTable = BUILTIN) -> Any:
    """Validate the ``source:`` section into the kind's frozen config."""
    origin = origin or {}
    if not isinstance(data, Mapping):
        raise ConfigError("source", "must be a mapping with kind: " + ", ".join(sources), data,
                          origin.get("source", source))
    kind = data.get("kind")
    if kind not in sources:
        raise ConfigError("source.kind", f"must be one of {', '.join(sources)}", kind,
                          origin.get("source.kind", source))
    options = {k: v for k, v in data.items() if k != "kind"}
    return importlib.import_module(sources[kind][0]).Config.from_dict(options, source, base_dir, origin)


def create_source(config: Any, **kwargs: Any) -> FrameSource:
    """Build (not open) the source for a validated source config (its module names the class)."""
    module = importlib.import_module(type(config).__module__)
    return getattr(module, config.SOURCE_CLASS)(config, **kwargs)


__all__ = ["BUILTIN", "SourceTable", "Frame", "FrameSource", "EndOfStream", "create_source",
           "source_config_from_dict", "source_keys"]
