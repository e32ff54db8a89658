"""``--set KEY=VALUE``: change single parameters of a parameter file from the command line (evaluate, tune)."""

from __future__ import annotations

import argparse


def add_set_option(p: argparse.ArgumentParser, what: str) -> None:
    """The repeatable ``--set`` option; ``what`` says which parameters it changes."""
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help=f"change one parameter of {what}, e.g. --set sgbm.num_disparities=64 (repeatable)")


def parse_sets(items: list[str]) -> dict:
    """``--set KEY=VALUE`` items -> {dotted key: YAML value}; ConfigError naming --set when malformed."""
    import yaml

    from uav_depth.core.errors import ConfigError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key.count(".") != 1:
            raise ConfigError("--set", "must look like SECTION.KEY=VALUE (sgbm.num_disparities=64)", item)
        try:
            out[key] = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError:
            out[key] = value
    return out


def apply_sets(params, items: list[str]):
    """``params`` with the ``--set`` items applied (validated by the schema like a file's keys)."""
    from uav_depth.core.errors import ConfigError

    sets = parse_sets(items)
    try:
        return params.replace(**sets) if sets else params
    except ConfigError as exc:       # the command line is to blame, not a file
        raise ConfigError(exc.key, exc.rule, exc.value, source="--set") from None
