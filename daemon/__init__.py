"""uav_depth.daemon: the on-board runtime, what flies on the drone.

Frame sources (real cameras and replay), ranging, the MAVLink link, hot reload,
sd_notify, the frame logger and the service that ties them together (``service``:
start-up, main loop, shutdown; ``capture``: the capture thread; ``stage``: the
stereo stage and its reload; ``health``: what the service reports). It imports
only :mod:`uav_depth.core`; the simulator plugs its synthetic source in through
the :mod:`uav_depth.core.frames` interface, handed over by the CLI.
"""
