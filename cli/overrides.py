"""``--set KEY=VALUE``: the one rule for every command that takes it (run, sitl, evaluate, tune).

An item is ``KEY=VALUE``: a dotted key with no empty part, and a value read as YAML the
way a ``UAV_DEPTH_*`` variable is (:func:`uav_depth.daemon.config.parse_value`). Which
keys exist is the schema's to say: the run config's loader for ``run`` and ``sitl``, the
parameter schema for ``evaluate`` and ``tune`` (every parameter key is ``SECTION.KEY``).
A bad item, malformed or unknown to the schema, is a ConfigError naming it: one line and
exit 78 from :mod:`uav_depth.cli.main`.
"""

from __future__ import annotations

import argparse
from typing import Any

#: What a parameter-file item looks like: two dotted parts, and an example.
PARAMETER_PARTS, PARAMETER_EXAMPLE = 2, "sgbm.num_disparities=64"
#: A run-config item: any depth (``params_file=...``, ``source.scene.seed=3``).
CONFIG_EXAMPLE = "mavlink.rate_hz=25"


def add_set_option(p: argparse.ArgumentParser, what: str, example: str = PARAMETER_EXAMPLE, more: str = "") -> None:
    """The repeatable ``--set`` option; ``what`` says which keys it changes, ``more`` anything to add."""
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help=f"change one key of {what} (dotted key, YAML value), e.g. --set {example}{more} (repeatable)")


def parse_sets(items: list[str], parts: int | None = None, example: str = CONFIG_EXAMPLE) -> dict[str, Any]:
    """``--set`` items -> {dotted key: value}, the last of a key winning.

    ``parts``: how many dotted parts every key must have (None: any). Raises ConfigError
    naming ``--set`` and the item when one is malformed.
    """
    from uav_depth.core.errors import ConfigError
    from uav_depth.daemon.config import parse_value

    form = ("SECTION.KEY" if parts == 2 else "KEY") + "=VALUE"
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        dotted = key.split(".")
        if not sep or not all(dotted) or (parts is not None and len(dotted) != parts):
            raise ConfigError("--set", f"must look like {form} ({example})", item)
        out[key] = parse_value(value)
    return out


def apply_sets(params, items: list[str]):
    """``params`` (a StereoParams) with the ``--set`` items applied, validated by the schema as a file's keys
    are: an unknown section or key is a ConfigError naming ``--set``, as a value out of bounds is."""
    from uav_depth.core.params import params_from_dict

    sets = parse_sets(items, PARAMETER_PARTS, PARAMETER_EXAMPLE)
    if not sets:
        return params
    data: dict[str, Any] = params.to_dict()
    for key, value in sets.items():
        section, name = key.split(".")
        data.setdefault(section, {})[name] = value
    return params_from_dict(data, source="--set")
