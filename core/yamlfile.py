"""Reading YAML files: one loader for every YAML file the project reads (config, parameters, calibration).

On top of PyYAML's safe loader: the file must be UTF-8 text (see
:func:`~uav_depth.core.fileio.read_text_file`), and a key given twice in one
mapping is an error naming the key path and both lines (PyYAML keeps the last
one silently, so a typo'd copy would win unseen).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.fileio import read_text_file


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
    """The document in ``text`` (None when empty). Syntax errors: FileFormatError with the line;
    duplicate keys: ConfigError naming the key path and both lines."""
    loader = yaml.SafeLoader(text)
    try:
        try:
            node = loader.get_single_node()
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
    """Read and parse a YAML file; every failure is one FileFormatError or ConfigError naming ``path``."""
    path = Path(path)
    return parse_yaml(read_text_file(path, what), str(path), what)
