"""Trying a parameter set where a native crash cannot take the daemon down: in a child process.

OpenCV is native code: parameters it cannot take may kill the process (SIGFPE from a division
by zero, SIGSEGV) instead of raising, and no Python handler can catch that. So the first run of
a new parameter set, the test render (:func:`uav_depth.daemon.stage.test_render`), happens in a
child process (``python -m uav_depth.daemon.trial_child``), before the parameters are swapped
in, at start-up, by ``run --check`` and by ``params check``. A child that dies of a signal, exits
without answering, or does not answer within the time bound refuses the parameters with one
:class:`~uav_depth.core.errors.ConfigError` naming the file and what happened ("OpenCV crashed
with SIGFPE on the test render"); the daemon keeps flying what it flies.

The child starts on first use and answers trials one at a time over its stdin and stdout (a
pickled :class:`Job` in, one JSON line out), so a burst of trials (``params check`` of many
files, the schema fuzz) pays Python's start once; it exits by itself after :data:`IDLE_S` without
work or when the parent goes. It lowers its own priority (nice +:data:`NICENESS`, where the system
allows) so that the daemon's stereo thread keeps the CPU while it works; the parent's thread
waits in ``select`` without the GIL.
"""

from __future__ import annotations

import json
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from typing import Any

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import StereoParams
from uav_depth.core.ranging import RangingConfig


#: The longest a trial may take, start of the child included, unless the caller says otherwise.
TIMEOUT_S = 30.0
#: The child exits after this long without a trial; the parent starts a new one rather than reuse a
#: child idle for half of it (so it never writes to one that is just leaving).
IDLE_S = 60.0
#: How much the child lowers its priority below the daemon's.
NICENESS = 10
#: The length prefix of a pickled job on the child's stdin.
LEN = struct.Struct("!I")


@dataclass(frozen=True)
class Job:
    """One trial: build the stage of ``params`` for this camera and ROI, measure the test render."""

    params: StereoParams
    origin: str
    ranging: RangingConfig
    calibration: Calibration
    roi: tuple[int, int, int, int]


@dataclass(frozen=True)
class Outcome:
    """What the child answered: why the test render measured nothing (None: it measured), at ``distance_m``."""

    why: str | None
    distance_m: float


class Trials:
    """The parent's side: runs :class:`Job` s in the child, one at a time (thread-safe)."""

    def __init__(self, timeout_s: float = TIMEOUT_S):
        self.timeout_s = timeout_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._stderr: Any = None
        self._last_used = 0.0
        self._lock = threading.Lock()
        self.started = 0          # children started (one per crash, hang or idle exit)

    def run(self, job: Job) -> Outcome:
        """The test render of ``job`` in the child; ConfigError when the child crashed, hung or failed."""
        blob = pickle.dumps(job)
        with self._lock:
            for _ in range(2):      # a child that left cleanly (idle) before reading the job: once more
                line, failure, code = self._try(blob)
                if line or code != 0:
                    break
            self._last_used = time.monotonic()
        if failure is not None:
            raise ConfigError("(parameters)", "must run the test render without crashing (tried in a child "
                              "process)", failure, job.origin)
        answer = json.loads(line)
        if "error" in answer:
            raise ConfigError("(parameters)", "must build and run on the test render", answer["error"], job.origin)
        return Outcome(answer["why"], answer["z"])

    def _try(self, blob: bytes) -> tuple[bytes, str | None, int | None]:
        """(answer line, or b""; what happened when there is none; the child's exit code when it ended)."""
        try:
            proc = self._child()
        except OSError as exc:      # this interpreter cannot be started again (permissions, no memory)
            return b"", f"the trial process could not be started ({type(exc).__name__}: {exc})", None
        try:
            os.write(proc.stdin.fileno(), LEN.pack(len(blob)) + blob)
            line = self._answer(proc)
        except TimeoutError:
            self._proc = None
            _end(proc)
            return b"", f"the test render did not finish within {self.timeout_s:g} s (the child was killed)", None
        except BrokenPipeError:
            line = b""
        if line:
            return line, None, None
        self._proc = None
        code = _end(proc)
        if code is not None and code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            return b"", f"OpenCV crashed with {name} on the test render", code
        return b"", f"the trial process exited with code {code} before answering{_tail(self._stderr)}", code

    def close(self) -> None:
        """End the child (if any) now; a trial in progress on another thread then fails (that thread,
        waiting on the child's pipe, reaps it: the pipe is not closed under it)."""
        proc = self._proc
        if proc is None:
            return
        if self._lock.acquire(blocking=False):
            try:
                self._proc = None
                _end(proc)
            finally:
                self._lock.release()
        else:
            proc.kill()

    def _child(self) -> subprocess.Popen[bytes]:
        proc = self._proc
        if proc is not None and proc.poll() is None and time.monotonic() - self._last_used < IDLE_S / 2:
            return proc
        if proc is not None:
            _end(proc)
        if self._stderr is not None:
            self._stderr.close()
        self._stderr = tempfile.TemporaryFile()
        self._proc = subprocess.Popen([sys.executable, "-m", "uav_depth.daemon.trial_child"],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr,
                                      close_fds=True)
        self.started += 1
        return self._proc

    def _answer(self, proc: subprocess.Popen[bytes]) -> bytes:
        """One line from the child within the time bound (b"" when it ended first)."""
        fd, buf = proc.stdout.fileno(), b""
        deadline = time.monotonic() + self.timeout_s
        while not buf.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError
            ready, _, _ = select.select([fd], [], [], left)
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    return b""
                buf += chunk
        return buf


def _end(proc: subprocess.Popen[bytes]) -> int | None:
    """Stop ``proc`` (closing its stdin, then SIGKILL) and reap it; its exit code."""
    for stream in (proc.stdin, proc.stdout):
        try:
            stream.close()
        except OSError:
            pass
    try:
        return proc.wait(0.5)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def _tail(stderr: Any) -> str:
    try:
        stderr.seek(0)
        lines = stderr.read()[-2000:].decode("utf-8", "replace").strip().splitlines()
    except (OSError, ValueError):
        return ""
    return f" ({lines[-1].strip()})" if lines else ""
