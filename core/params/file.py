"""Parameter files: read and validate one (strictly), read its provenance, write one atomically."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

import yaml

from uav_depth.core.errors import ConfigError
from uav_depth.core.fileio import atomic_write_text
from uav_depth.core.params.checks import check_computable
from uav_depth.core.params.schema import SECTIONS, StereoParams, params_from_dict
from uav_depth.core.yamlfile import load_yaml_file


def load_params(path: str | os.PathLike[str]) -> StereoParams:
    """Read and validate a parameter file. Errors name the file, key, rule and value.

    Stricter than :func:`params_from_dict`: the file must be UTF-8 YAML with no key
    given twice, must set at least one section (an empty file is an error, not the
    defaults), and must pass :func:`check_computable`.
    """
    path = Path(path)
    data = load_yaml_file(path, "parameter file")
    params = params_from_dict(data, source=str(path))
    if data is None or not any(k in SECTIONS for k in data):
        raise ConfigError("(file)", f"must set at least one section ({', '.join(SECTIONS)}); an empty file is "
                          "not taken as the defaults (write them with: uav-depth params default)",
                          "" if data is None else data, str(path))
    return check_computable(params, str(path))


def read_provenance(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``provenance`` mapping of a parameter file ({} when absent)."""
    data = load_yaml_file(path, "parameter file") or {}
    prov = data.get("provenance") if isinstance(data, Mapping) else None
    return dict(prov) if isinstance(prov, Mapping) else {}


class _FileDumper(yaml.SafeDumper):
    """Safe YAML with lists of plain numbers on one line: ``roi: [0.3, 0.3, 0.7, 0.7]``."""


_FileDumper.add_representer(
    list, lambda dumper, data: dumper.represent_sequence(
        "tag:yaml.org,2002:seq", data,
        flow_style=all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data) or None))


def dump_params(params: StereoParams, provenance: Mapping[str, Any] | None = None) -> str:
    """YAML text of ``params`` (and provenance), guaranteed to load back equal."""
    doc: dict[str, Any] = params.to_dict()
    if provenance:
        doc["provenance"] = json.loads(json.dumps(dict(provenance), default=str))
    text = yaml.dump(doc, Dumper=_FileDumper, sort_keys=False)
    if params_from_dict(yaml.safe_load(text)) != params:  # never write what the loader would not give back
        raise ConfigError("(file)", "must round-trip through the loader", text)
    return text


def save_params(params: StereoParams, path: str | os.PathLike[str],
                provenance: Mapping[str, Any] | None = None) -> Path:
    """Write ``params`` atomically: temp file in the same directory, fsync, rename.

    A reader (the daemon's hot reload) sees either the old file or the whole new
    one, never a half-written file; a file the loader would reject is never written.
    """
    return atomic_write_text(path, dump_params(params, provenance))
