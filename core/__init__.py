"""uav_depth.core: the stereo core shared by every room.

The parameter schema (:mod:`.params`), the disparity stages (:mod:`.disparity`),
calibration and rectification, and the log layout (:mod:`.session`). It imports
nothing of the project above it; the runtime, the simulator, the tuner and the
CLI all import it.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("uav-depth")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
