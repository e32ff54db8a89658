"""The trial child: ``python -m uav_depth.daemon.trial_child``, started by :class:`~uav_depth.daemon.trial.Trials`.

It reads pickled :class:`~uav_depth.daemon.trial.Job` s from stdin (length-prefixed), builds each
job's stage and measures its test render (:func:`uav_depth.daemon.stage.test_render`), and writes
one JSON line per job to its stdout: ``{"why": ..., "z": ...}``, or ``{"error": ...}`` for a
Python-level failure. A native crash ends it, which is the parent's answer. It leaves after
:data:`~uav_depth.daemon.trial.IDLE_S` without a job, or when its stdin closes.
"""

from __future__ import annotations

import json
import os
import pickle
import select
import signal
import sys
from typing import Any

from uav_depth.daemon.stage import make_stage, test_render
from uav_depth.daemon.trial import IDLE_S, LEN, NICENESS, Job


def _read_exactly(fd: int, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = os.read(fd, n - len(buf))
        if not chunk:
            return b""
        buf += chunk
    return buf


def _serve(fd_in: int, out: Any) -> int:
    while True:
        ready, _, _ = select.select([fd_in], [], [], IDLE_S)
        header = _read_exactly(fd_in, LEN.size) if ready else b""
        if not header:
            return 0                # idle, or the parent went: nothing more to try
        job: Job = pickle.loads(_read_exactly(fd_in, LEN.unpack(header)[0]))
        try:
            stage = make_stage(job.params, job.origin, job.ranging, job.calibration, job.roi)
            why, z = test_render(stage, job.calibration.width, job.calibration.height)
            answer: dict[str, Any] = {"why": why, "z": z}
        except Exception as exc:    # a Python-level failure is an answer; only a native crash is not
            answer = {"error": f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"}
        out.write(json.dumps(answer).encode() + b"\n")
        out.flush()


def main() -> int:
    try:
        os.nice(NICENESS)           # the stereo thread first; refused under some filters: run as we are
    except OSError:
        pass
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # a Ctrl-C is for the daemon, which ends the child
    answers = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                   # whatever a library prints goes to stderr, never into the answers
    return _serve(0, answers)


if __name__ == "__main__":
    sys.exit(main())
