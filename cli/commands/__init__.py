"""One module per ``uav-depth`` subcommand: ``configure(parser)`` and ``run(args) -> int``."""
