"""The frame-source table the commands accept: the runtime's own plus the simulator's.

The runtime (:mod:`uav_depth.daemon.sources`) knows only what flies; the synthetic
source lives in the simulator, which the runtime must not import. This module,
above both, composes the table that ``run``, ``sitl`` and ``sources`` hand to the
config loader. Entries name modules, so building the table imports nothing.
"""

from __future__ import annotations

from uav_depth.daemon.sources import BUILTIN

#: kind -> (module, source class, one-line help), the simulator's first.
SOURCES: dict[str, tuple[str, str, str]] = {
    "synthetic": ("uav_depth.sim.source", "SyntheticSource",
                  "ray-cast tree scene with a branch at a known distance, optionally moving (no hardware)"),
    **BUILTIN,
}
