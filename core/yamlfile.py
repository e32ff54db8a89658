"""Reading YAML files: one loader for every YAML file the project reads (config, parameters, calibration).

On top of PyYAML's safe loader: the file must be UTF-8 text of at most
:data:`MAX_YAML_BYTES` (see :func:`~uav_depth.core.fileio.read_text_file`); a key
given twice in one mapping is an error naming the key path and both lines (PyYAML
keeps the last one silently, so a typo'd copy would win unseen); and anchors and
aliases (``&name`` / ``*name``) are refused where the parser meets the first one:
nothing the project reads needs them, and a kilobyte of nested aliases expands
into billions of nodes (the "billion laughs"), which would hold the daemon for
seconds or exhaust its memory. Parsing is thereby bounded by the file's size.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.fileio import read_text_file

#: The most a YAML file (run config, parameter file, calibration) may hold: twenty times the largest the
#: project ships, and small enough that PyYAML's pure-Python parser reads it in a fraction of a second.
MAX_YAML_BYTES = 64 * 1024


class _NoAliases(Exception):
    def __init__(self, kind: str, name: str, line: int):
        super().__init__(f"{kind} (&{name} / *{name}) at line {line}")
        self.kind, self.name, self.line = kind, name, line


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader that refuses anchors and aliases before composing them."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            kind = "alias" if isinstance(event, yaml.AliasEvent) else "anchor"
            raise _NoAliases(kind, event.anchor, event.start_mark.line + 1)
        return super().compose_node(parent, index)


def _check_duplicates(node: yaml.Node, path: str, source: str | None) -> None:
    if isinstance(node, yaml.MappingNode):
        seen: dict[Any, int] = {}
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            line = key_node.start_mark.line + 1
            dotted = f"{path}.{key}" if path else str(key)
            if key is not None and key in seen:
                value = value_node.value if isinstance(value_node, yaml.ScalarNode) else "(a mapping or list)"
                raise ConfigError(dotted, f"is given twice (line {seen[key]} and line {line}); keep one",
                                  value, source)
            if key is not None:
                seen[key] = line
            _check_duplicates(value_node, dotted, source)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _check_duplicates(item, f"{path}[{i}]", source)


def parse_yaml(text: str, source: str | None = None, what: str = "file") -> Any:
    """The document in ``text`` (None when empty). Syntax errors, anchors and aliases: FileFormatError
    with the line; duplicate keys: ConfigError naming the key path and both lines."""
    loader = _Loader(text)
    try:
        try:
            node = loader.get_single_node()
        except _NoAliases as exc:
            raise FileFormatError(f"{source or '(text)'}: {what} uses a YAML {exc.kind} ('{exc.name}') at line "
                                  f"{exc.line}; anchors and aliases are not accepted: write each value out")
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}" if mark is not None else ""
            problem = getattr(exc, "problem", None) or str(exc)
            raise FileFormatError(f"{source or '(text)'}: {what} is not valid YAML{where}: {problem}") from exc
        if node is None:
            return None
        _check_duplicates(node, "", source)
        try:
            return loader.construct_document(node)
        except yaml.YAMLError as exc:
            raise FileFormatError(f"{source or '(text)'}: {what} is not valid YAML: {exc}") from exc
    finally:
        loader.dispose()


def load_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """Read and parse a YAML file of at most :data:`MAX_YAML_BYTES`; every failure is one FileFormatError
    or ConfigError naming ``path``."""
    path = Path(path)
    return parse_yaml(read_text_file(path, what, MAX_YAML_BYTES), str(path), what)
