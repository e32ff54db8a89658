"""uav_depth.core: the stereo core shared by every room.

The parameter schema (:mod:`.params`), the disparity stages (:mod:`.disparity`),
calibration and rectification, and the log layout (:mod:`.session`). It imports
nothing of the project above it; the runtime, the simulator, the tuner and the
CLI all import it.
"""



def __getattr__(name: str) -> str:
    # __version__ on first use: importlib.metadata costs ~0.1 s, and the daemon imports this
    # package before it can install its signal handlers (uav_depth.cli.signals).
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("uav-depth")
    except PackageNotFoundError:  # running from a source tree that is not installed
        value = "0+unknown"
    globals()["__version__"] = value
    return value
