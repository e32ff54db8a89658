"""uav_depth.daemon: the on-board runtime; owns the parameter schema and the disparity pipeline."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("uav-depth")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
