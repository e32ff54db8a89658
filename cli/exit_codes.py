"""Every exit code of ``uav-depth``, in one leaf module.

The command table (:mod:`uav_depth.cli.main`) imports the commands and the
commands return these codes, so they live here, importing nothing: the commands
need not import the table back. Where a code is one of sysexits', it keeps its
meaning there; docs/operations.md lists them for operators.
"""

EXIT_OK = 0
#: Any error not listed below.
EXIT_ERROR = 1
#: Bad command-line syntax (argparse's own code).
EXIT_USAGE = 2
#: check-rig: the pair is misaligned beyond the threshold.
EXIT_MISALIGNED = 3
#: check-rig: too few feature matches to tell.
EXIT_CANNOT_TELL = 4
#: sysexits' EX_UNAVAILABLE: ``run`` could not find its camera at start-up. Not in the unit's
#: RestartPreventExitStatus, so systemd retries until the camera appears.
EXIT_UNAVAILABLE = 69
#: sysexits' EX_CANTCREAT: an output exists (a session) and --overwrite was not given.
EXIT_CANTCREAT = 73
#: sysexits' EX_CONFIG: a config, parameter, calibration or key file, a ``--set`` or an input the
#: parameters cannot work on. The systemd unit lists it in RestartPreventExitStatus, so a typo in a
#: config does not restart-loop.
EXIT_CONFIG = 78
#: SIGINT in a command other than ``run`` / ``sitl`` (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130
