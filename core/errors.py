"""One small exception hierarchy for the whole package.

Library code raises these; only the CLI turns them into exit codes and one-line
messages. Each message states the rule, the key path and the value.
"""

from __future__ import annotations


class UavDepthError(Exception):
    """Base class of every error uav-depth raises on purpose."""


class ConfigError(UavDepthError, ValueError):
    """A configuration or parameter value breaks a rule.

    ``key`` is the dotted key path (``sgbm.num_disparities``), ``rule`` what the
    value must satisfy, ``value`` what was given.
    """

    def __init__(self, key: str, rule: str, value: object, source: str | None = None):
        self.key = key
        self.rule = rule
        self.value = value
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key} {rule}, but got {value!r}")


class FileFormatError(UavDepthError):
    """A file exists but cannot be read as what it claims to be."""


class CalibrationError(UavDepthError):
    """Calibration is missing or inconsistent."""


class SourceError(UavDepthError):
    """A frame source cannot deliver frames (camera missing, replay ended, ...)."""


#: Import name -> the pyproject extra that installs it. tests/deploy/test_base_install.py checks it
#: against pyproject.toml, so an extra added there without an entry here fails CI.
EXTRA_OF_MODULE = {
    "deap": "tuning", "skimage": "tuning", "matplotlib": "tuning", "tqdm": "tuning", "optuna": "tuning",
    "depthai": "oak", "ray": "ray", "onnxruntime": "onnx",
}


class LinkError(UavDepthError):
    """The MAVLink link cannot be opened as configured (a missing serial device, a port another program holds)."""


class DependencyError(UavDepthError):
    """An optional dependency (an extra) is needed but not installed."""

    def __init__(self, module: str, extra: str, purpose: str):
        super().__init__(
            f"{purpose} needs the Python module {module!r}: "
            f"install it with pip install 'uav-depth[{extra}]'"
        )

    @classmethod
    def from_missing(cls, exc: ModuleNotFoundError, purpose: str) -> "DependencyError | None":
        """The DependencyError for an extra's module that failed to import; None if it is no extra's."""
        module = (exc.name or "").split(".")[0]
        extra = EXTRA_OF_MODULE.get(module)
        return None if extra is None else cls(module, extra, purpose)


class FrameError(UavDepthError, ValueError):
    """A stereo pair is unusable (empty, mismatched sizes, wrong dtype)."""


class OutputExistsError(UavDepthError):
    """An output (a session directory) exists and must not be overwritten without being told to."""


class ParameterWarning(UserWarning):
    """Parameters that validate but that OpenCV cannot compute meaningfully."""
