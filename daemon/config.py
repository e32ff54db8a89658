"""The run config of ``uav-depth run``: one YAML file, validated once, frozen.

Sections: ``source`` (which frames), ``calibration`` (file or inline), ``params_file``
(the hot-reloaded stereo parameters), ``ranging`` (branch distance), ``mavlink``
(DISTANCE_SENSOR output), ``logging`` (frames for tuning) and ``service``
(lifecycle knobs). Every key is declared once in a :class:`Key` table with its
type, bounds and meaning; the loader, the environment overrides and the README
reference read those tables.

Settings resolve, first wins: an explicit argument (``--set mavlink.url=...``), a
``UAV_DEPTH_<SECTION>_<KEY>`` environment variable (``UAV_DEPTH_MAVLINK_RATE_HZ=25``,
``UAV_DEPTH_PARAMS_FILE=...``), the config file, the default. Errors name the key
path, the rule and the value, and where the value came from.

The runtime's own sections (``mavlink``, ``logging``, ``service``) are declared in
:mod:`uav_depth.daemon.sections`; the others beside the part they configure.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

from uav_depth.core.calibration import Calibration, calibration_from_dict, load_calibration
from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.keys import Key, section_values
from uav_depth.daemon.liveview import LiveViewConfig
from uav_depth.daemon.obstacles import ObstacleConfig
from uav_depth.core.ranging import RangingConfig
from uav_depth.daemon.rigwatch import RigCheckConfig
from uav_depth.daemon.sections import LoggingConfig, MavlinkConfig, ServiceConfig
from uav_depth.daemon.sources import BUILTIN, SourceTable, source_config_from_dict, source_keys
from uav_depth.core.yamlfile import load_yaml_file, parse_yaml

log = logging.getLogger("uav_depth.config")

ENV_PREFIX = "UAV_DEPTH_"
#: Environment variables with a meaning of their own (not a config key).
ENV_RESERVED = ("UAV_DEPTH_CONFIG",)


SECTION_CLASSES: dict[str, type] = {"ranging": RangingConfig, "mavlink": MavlinkConfig,
                                    "logging": LoggingConfig, "service": ServiceConfig, "liveview": LiveViewConfig,
                                    "rig_check": RigCheckConfig, "obstacle_distance": ObstacleConfig}
TOP_KEYS = ("source", "calibration", "params_file", *SECTION_CLASSES)


@dataclass(frozen=True)
class RunConfig:
    """The whole validated run config. Build with :func:`load_run_config` or :func:`run_config_from_dict`."""

    source: Any                         # the source's own frozen config (see uav_depth.daemon.sources)
    calibration: Calibration | None = None
    params_file: Path | None = None
    ranging: RangingConfig = RangingConfig()
    mavlink: MavlinkConfig = MavlinkConfig()
    logging: LoggingConfig = LoggingConfig()
    service: ServiceConfig = ServiceConfig()
    liveview: LiveViewConfig = LiveViewConfig()
    rig_check: RigCheckConfig = RigCheckConfig()
    obstacle_distance: ObstacleConfig = ObstacleConfig()
    origin: Mapping[str, str] = field(default_factory=dict, compare=False)   # key -> where it came from

    @property
    def source_kind(self) -> str:
        return self.source.KIND

    def summary(self) -> str:
        return (f"source {self.source_kind}, mavlink {self.mavlink.url} at {self.mavlink.rate_hz:g} Hz, "
                f"params {self.params_file or 'built-in defaults'}, "
                f"logging {self.logging.dir or 'off'}"
                + (f", live view http://{self.liveview.host}:{self.liveview.port}/" if self.liveview.enabled else ""))




def _calibration(value: Any, base: Path | None, source: str | None) -> Calibration | None:
    if value is None:
        return None
    if isinstance(value, Mapping):
        return calibration_from_dict(value, source)
    if isinstance(value, str) and value:
        path = Path(os.path.expanduser(value))
        if not path.is_absolute() and base is not None:
            path = base / path
        return load_calibration(path)
    raise ConfigError("calibration", "must be a file path or a mapping (focal_px, baseline_m, width, height)",
                      value, source)


def run_config_from_dict(data: Any, source: str | None = None, base_dir: Path | None = None,
                         origin: Mapping[str, str] | None = None, sources: SourceTable = BUILTIN) -> RunConfig:
    """Validate a nested mapping into a :class:`RunConfig`.

    Relative paths (calibration, params_file, logging.dir, mavlink.signing_key_file, replay path) are taken
    relative to ``base_dir`` (the config file's directory). ``sources``: the frame
    source kinds accepted (the CLI adds the simulator's to the runtime's own).
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError("(top level)", "must be a mapping of sections", type(data).__name__, source)
    origin = dict(origin or {})
    src = lambda key: origin.get(key, source)  # noqa: E731  where a key's value came from
    for top in data:
        if top not in TOP_KEYS:
            raise ConfigError(str(top), f"is not a known section (known: {', '.join(TOP_KEYS)})", data[top],
                              src(str(top)))
    if data.get("source") is None:
        raise ConfigError("source", f"is required (a mapping with kind: {', '.join(sources)})", None, source)
    source_cfg = source_config_from_dict(data["source"], source, base_dir, origin, sources)
    calibration = _calibration(data.get("calibration"), base_dir, src("calibration"))
    params_file = Key("params_file", "path", None, "", optional=True).validate(
        "", data.get("params_file"), src("params_file"))
    if params_file is not None and not params_file.is_absolute() and base_dir is not None:
        params_file = base_dir / params_file
    sections = {name: cls(**section_values(cls.KEYS, data.get(name), name, source, origin=origin))
                for name, cls in SECTION_CLASSES.items()}
    if sections["logging"].dir is not None and not sections["logging"].dir.is_absolute() and base_dir is not None:
        sections["logging"] = replace(sections["logging"], dir=base_dir / sections["logging"].dir)
    key_file = sections["mavlink"].signing_key_file
    if key_file is not None and not key_file.is_absolute() and base_dir is not None:
        sections["mavlink"] = replace(sections["mavlink"], signing_key_file=base_dir / key_file)
    mav = sections["mavlink"]
    if (mav.system_id, mav.component_id) == (1, 1):
        raise ConfigError("mavlink.component_id", "must not be 1 when system_id is 1 (ArduPilot drops messages "
                          "carrying its own ids as a loopback)", 1, src("mavlink.component_id"))
    svc = sections["service"]
    if svc.reconnect_max_s < svc.reconnect_min_s:
        raise ConfigError("service.reconnect_max_s", f"must be at least service.reconnect_min_s "
                          f"({svc.reconnect_min_s:g})", svc.reconnect_max_s, source)
    return RunConfig(source=source_cfg, calibration=calibration, params_file=params_file, origin=origin,
                     **sections)


# -- resolution: argument > environment > file > default ------------------------------------

def env_keys(sources: SourceTable = BUILTIN) -> dict[str, str]:
    """``UAV_DEPTH_*`` variable name -> dotted config key, for every settable key."""
    out = {f"{ENV_PREFIX}PARAMS_FILE": "params_file", f"{ENV_PREFIX}CALIBRATION": "calibration"}
    for name, cls in SECTION_CLASSES.items():
        for k in cls.KEYS:
            out[f"{ENV_PREFIX}{name.upper()}_{k.name.upper()}"] = f"{name}.{k.name}"
    out[f"{ENV_PREFIX}SOURCE_KIND"] = "source.kind"
    for kind in sources:
        for k in source_keys(kind, sources):
            out[f"{ENV_PREFIX}SOURCE_{k.name.upper()}"] = f"source.{k.name}"
    return out


def parse_value(text: str) -> Any:
    """A setting given as text (environment, ``--set``): a YAML scalar or flow list/mapping.

    Read by the one YAML loader (no anchors or aliases, no key twice); text that is not such
    YAML stays text, and the key's own rule then names it.
    """
    try:
        return parse_yaml(text, "(setting)", "setting") if text.strip() else None
    except FileFormatError:
        return text


def _set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    node = data
    for p in parts[:-1]:
        child = node.get(p)
        if not isinstance(child, dict):
            child = {} if child is None or not isinstance(child, Mapping) else dict(child)
            node[p] = child
        node = child
    node[parts[-1]] = value


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The config file as a mapping ({} when empty). Unreadable, not UTF-8 text, not YAML, a key given
    twice: one FileFormatError or ConfigError naming the file."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise ConfigError("--config", "must name an existing file", str(path))
    data = load_yaml_file(path, "config")
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError("(top level)", "must be a mapping of sections", type(data).__name__, str(path))
    return _deep_copy(data)


def _deep_copy(d: Any) -> Any:
    if isinstance(d, Mapping):
        return {k: _deep_copy(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_deep_copy(v) for v in d]
    return d


def load_run_config(path: str | os.PathLike[str] | None = None, overrides: Mapping[str, Any] | None = None,
                    environ: Mapping[str, str] | None = None, sources: SourceTable = BUILTIN) -> RunConfig:
    """Resolve and validate the run config.

    ``path``: the YAML file (None: ``UAV_DEPTH_CONFIG`` or no file). ``overrides``:
    dotted key -> value given explicitly (command line); they win over
    ``UAV_DEPTH_*`` variables in ``environ`` (default ``os.environ``), which win
    over the file. Unknown ``UAV_DEPTH_*`` variables are logged, not fatal.
    ``sources``: the frame source kinds accepted.
    """
    data, source, base_dir, origin = _resolve(path, overrides, environ, sources)
    return run_config_from_dict(data, source, base_dir, origin, sources)


def load_section(name: str, path: str | os.PathLike[str] | None = None, environ: Mapping[str, str] | None = None,
                 sources: SourceTable = BUILTIN, whole_file: bool = False) -> tuple[Any, str]:
    """One section of :data:`SECTION_CLASSES` (e.g. ``ranging``) as ``run`` would resolve it from the same file
    and ``UAV_DEPTH_*`` variables (:func:`load_run_config`), without needing the rest of a run config (a frame
    source); and where it came from, in words. ``whole_file``: when there is a config file, it is validated
    whole, as run would (a file run would refuse is refused), and the section taken from it."""
    data, source, base_dir, origin = _resolve(path, None, environ, sources)
    cls = SECTION_CLASSES[name]
    if whole_file and source is not None:
        section = getattr(run_config_from_dict(data, source, base_dir, origin, sources), name)
    else:
        section = cls(**section_values(cls.KEYS, data.get(name), name, source, origin=origin))
    env = sorted({o for k, o in origin.items() if k.startswith(name + ".")})
    where = ([f"the {name} settings of {source}"] if source else []) + env
    return section, " and ".join(where) if where else f"the default {name} settings (no config file)"


def _resolve(path: str | os.PathLike[str] | None, overrides: Mapping[str, Any] | None,
             environ: Mapping[str, str] | None,
             sources: SourceTable) -> tuple[dict[str, Any], str | None, Path | None, dict[str, str]]:
    """(the settings as one mapping, the file they came from, its folder, where each key set came from): the
    file, then ``UAV_DEPTH_*`` variables, then ``overrides`` (:func:`load_run_config` says the order)."""
    environ = os.environ if environ is None else environ
    if path is None and environ.get("UAV_DEPTH_CONFIG"):
        path = environ["UAV_DEPTH_CONFIG"]
    data: dict[str, Any] = {}
    source = None
    base_dir = None
    if path is not None:
        data = read_config_file(path)
        source = str(path)
        base_dir = Path(path).resolve().parent
    origin: dict[str, str] = {}
    known = env_keys(sources)
    for name in sorted(environ):
        if not name.startswith(ENV_PREFIX) or name in ENV_RESERVED:
            continue
        dotted = known.get(name)
        if dotted is None:
            log.warning("ignoring unknown environment variable %s (known: %s)", name,
                        ", ".join(sorted(set(known) | set(ENV_RESERVED))))
            continue
        _set_dotted(data, dotted, parse_value(environ[name]))
        origin[dotted] = f"environment {name}"
        origin.setdefault(dotted.split(".")[0], f"environment {name}")
    for dotted, value in (overrides or {}).items():
        _set_dotted(data, dotted, value)
        origin[dotted] = "command line"
        origin.setdefault(dotted.split(".")[0], "command line")
    return data, source, base_dir, origin


def reference_markdown(sources: SourceTable = BUILTIN) -> str:
    """The config reference: every key of every section, from the tables above."""
    rows = ["| key | default | accepted | meaning |", "|---|---|---|---|"]
    rows.append("| `params_file` | null | path, or null | stereo parameter file, hot-reloaded; null or absent "
                "file: built-in manual defaults |")
    rows.append("| `calibration` | null | path, mapping, or null | stereo calibration (file or inline); "
                "null: the source's own |")
    rows.append(f"| `source.kind` | (required) | {' / '.join(sources)} | frame source |")
    for kind in sources:
        for k in source_keys(kind, sources):
            rows.append(f"| `source.{k.name}` ({kind}) | {_default(k)} | {k.accepted()} | {k.doc} |")
    for name, cls in SECTION_CLASSES.items():
        for k in cls.KEYS:
            rows.append(f"| `{name}.{k.name}` | {_default(k)} | {k.accepted()} | {k.doc} |")
    return "\n".join(rows)


def _default(k: Key) -> str:
    if k.default is None:
        return "null" if k.optional else "(required)"
    if isinstance(k.default, bool):
        return str(k.default).lower()
    return str(k.default)


__all__ = ["Key", "RunConfig", "load_section", "RangingConfig", "MavlinkConfig", "LoggingConfig", "ServiceConfig",
           "load_run_config", "run_config_from_dict", "section_values", "reference_markdown", "env_keys"]


def _fields_match() -> None:  # the KEYS tables and the dataclass fields must agree
    for cls in SECTION_CLASSES.values():
        names = [f.name for f in fields(cls)]
        assert names == [k.name for k in cls.KEYS], cls
        for f, k in zip(fields(cls), cls.KEYS):
            assert f.default == k.default, (cls, f.name)


_fields_match()
