"""Daemon pipeline benchmark: flight settings vs OpenCV's sample pipeline on synthetic 1280x720 scenes.

Same as ``uav-depth bench``; arguments are passed through, e.g.
``python bench/pipeline_bench.py --levers`` or ``--json``.
"""

import sys

from uav_depth.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
