"""uav_depth.sim: the simulator, what only runs on a laptop.

The ray-cast tree scene (:mod:`.scene`), the synthetic frame source that
implements the frame-source interface the runtime reads
(:class:`~uav_depth.core.frames.FrameSource`, :mod:`.source`), and the SITL pose
link (:mod:`.sitl`). It imports only the core.
"""
