"""uav_depth.sim: the simulator, what only runs on a laptop.

The ray-cast tree scene (:mod:`.scene`), the synthetic frame source that
implements the runtime's :class:`~uav_depth.daemon.sources.base.FrameSource`
(:mod:`.source`), and the SITL pose link (:mod:`.sitl`). It imports the core and,
of the runtime, only the interfaces it implements.
"""
