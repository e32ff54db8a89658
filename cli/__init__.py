"""uav_depth.cli: the ``uav-depth`` command line, on top of every room.

It imports everything and nothing imports it. It owns the subcommands
(:mod:`.main`), the lazy imports of extras, the mapping of errors to exit codes,
and the composition of rooms that no lower room may do itself (the frame-source
table with the simulator's source in it, the SITL loop, the benchmark).
"""
