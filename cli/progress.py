"""Progress on a terminal: every phase that can last seconds says what it does, and long ones count.

Lines go to stderr and only when stderr is a terminal, as tune's progress bar
(tqdm's ``disable=None``) does: logs, pipes and ``--json`` output stay clean. A
phase prints one line when it starts (``rendering 12 synthetic pairs ...``); a
phase of many steps prints ``  WHAT done/total`` for the first step, then at most
every ``every_s`` seconds, and for the last one, so that no terminal stays silent
longer than one step: a user who sees nothing for seconds cannot tell work from a hang.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO


class Progress:
    """Phase and step lines for a terminal's stderr; silent elsewhere (or with ``enabled=False``).

    ``stream``: where to write (default: ``sys.stderr`` at the time of each line, so
    tests may swap it). ``enabled``: None (default) decides by ``stream.isatty()``.
    """

    def __init__(self, stream: TextIO | None = None, every_s: float = 1.0, enabled: bool | None = None):
        self._stream = stream
        self.every_s = every_s
        self.enabled = enabled
        self._last: dict[str, float] = {}

    @property
    def stream(self) -> TextIO:
        return self._stream if self._stream is not None else sys.stderr

    def on(self) -> bool:
        """Whether lines are printed: ``enabled``, else whether the stream is a terminal."""
        if self.enabled is not None:
            return self.enabled
        isatty = getattr(self.stream, "isatty", None)
        return bool(isatty and isatty())

    def phase(self, text: str) -> None:
        """A phase begins: one line, ``text ...``."""
        if self.on():
            print(f"{text} ...", file=self.stream, flush=True)

    def step(self, what: str, done: int, total: int) -> None:
        """``done`` of ``total`` steps of ``what`` finished: ``  what done/total`` for the first and the last
        step, and in between at most every ``every_s`` seconds."""
        if not self.on():
            return
        now = time.monotonic()
        last = self._last.get(what)
        if last is None or done >= total or now - last >= self.every_s:
            print(f"  {what} {done}/{total}", file=self.stream, flush=True)
            self._last[what] = now

    def counter(self, what: str) -> Callable[[int, int], None]:
        """``progress(done, total)`` for APIs that report steps that way (e.g. ``sim.scene.write_session``)."""
        return lambda done, total: self.step(what, done, total)


class Counted:
    """An executor (``imap(tasks, stop)``, as :mod:`uav_depth.tuning.executor`'s) that counts on a terminal
    how many of each batch's tasks finished; everything else is the wrapped executor's."""

    def __init__(self, executor, progress: Progress, what: str):
        self._executor, self._progress, self._what = executor, progress, what

    def imap(self, tasks, stop=None):
        tasks = list(tasks)
        for done, item in enumerate(self._executor.imap(tasks, stop), 1):
            self._progress.step(self._what, done, len(tasks))
            yield item

    def __getattr__(self, name):
        return getattr(self._executor, name)


#: For library calls made where nobody watches (``--json``, tests).
QUIET = Progress(enabled=False)


def progress_line(what: str, every_s: float = 1.0) -> Callable[[int, int], None]:
    """A ``progress(done, total)`` printing ``  WHAT done/total`` to a terminal's stderr (see :class:`Progress`)."""
    return Progress(every_s=every_s).counter(what)


__all__ = ["Counted", "Progress", "QUIET", "progress_line"]
